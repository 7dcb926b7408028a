"""The layout of ``session.mcap``: topics, schemas and the lossless value encodings that
the recorder (writer) and the session reader share.

Every ROS 2 topic is what standard tools (Foxglove, ``ros2 bag``) display; each has a
JSON companion under ``/lasercal/...`` holding what a ROS message cannot carry exactly
(float64 host time, device time, sequence number, the UR rotation vector), so that a
recording gives back bit-for-bit the values the live run saw. See docs/recorder.md.
"""

from __future__ import annotations

import base64
import dataclasses
import enum
import json
import math
from pathlib import PurePath
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lasercal_hw.models import ScanGeometry

FORMAT_NAME = "lasercal-session"
FORMAT_VERSION = 1

TOPIC_SCAN = "/scan"
TOPIC_TCP_POSE = "/tcp_pose"
TOPIC_JOINT_STATES = "/joint_states"
TOPIC_META = "/lasercal/meta"
TOPIC_EVENT = "/lasercal/event"
TOPIC_SCAN_INFO = "/lasercal/scan_info"
TOPIC_TCP_POSE_EXACT = "/lasercal/tcp_pose"
TOPIC_JOINT_STATES_EXACT = "/lasercal/joint_states"
#: A cell job's one recording: each scanner's frame in the base frame (its nominal pose, then its
#: calibrated one), so a viewer shows every scan plane in one scene (docs/recorder.md).
TOPIC_TF_STATIC = "/tf_static"

FRAME_LASER = "laser"
FRAME_BASE = "base"

#: Meta and event key: the scanner whose run wrote the document (a cell job; docs/recorder.md).
META_SCANNER_NAME = "scanner_name"
#: Meta key of a cell job's one recording (its first, untagged meta document): the scanners the
#: job runs, in order. Its presence makes a file a job recording (``SessionRecording.for_scanner``).
META_JOB_SCANNERS = "job_scanners"


def scan_topics(scanner: str | None = None) -> tuple[str, str, str]:
    """A scanner's ``LaserScan`` topic, its ``scan_info`` companion and its frame: the run's
    own scanner (``None``) on ``/scan`` in ``laser``; a cell's other scanner NAME, watching
    the run's waypoints (docs/cell.md), on ``/scan/NAME`` and ``/lasercal/scan_info/NAME``
    in ``laser_NAME``."""
    if scanner is None:
        return TOPIC_SCAN, TOPIC_SCAN_INFO, FRAME_LASER
    return f"{TOPIC_SCAN}/{scanner}", f"{TOPIC_SCAN_INFO}/{scanner}", f"{FRAME_LASER}_{scanner}"


def scanner_of_topic(topic: str, family: str) -> tuple[bool, str | None]:
    """Whether ``topic`` is of the ``family`` (``TOPIC_SCAN`` or ``TOPIC_SCAN_INFO``) and whose
    (``None``: the run's own scanner; else the watching scanner's name): ``scan_topics``'s inverse."""
    if topic == family:
        return True, None
    if topic.startswith(family + "/") and len(topic) > len(family) + 1:
        return True, topic[len(family) + 1 :]
    return False, None


UR_JOINT_NAMES = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)


class EventKind(enum.StrEnum):
    """Kinds of ``/lasercal/event`` messages the reader understands (writers may add others)."""

    DWELL_START = "dwell_start"
    DWELL_END = "dwell_end"
    OBSERVATION = "observation"
    ABORT = "abort"
    FAULT = "fault"
    RESUME = "resume"
    RUN_END = "run_end"


# --- ROS 2 message definitions (ros2msg, with their dependencies appended) -------------

_SEPARATOR = "=" * 80
_TIME_DEF = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec"
_HEADER_DEF = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id"
_QUATERNION_DEF = "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1"


def _msgdef(main: str, *deps: str) -> str:
    return "\n".join([main.strip(), *(f"{_SEPARATOR}\n{dep}" for dep in deps)]) + "\n"


LASER_SCAN_TYPE = "sensor_msgs/msg/LaserScan"
LASER_SCAN_DEF = _msgdef(
    """
std_msgs/Header header
float32 angle_min
float32 angle_max
float32 angle_increment
float32 time_increment
float32 scan_time
float32 range_min
float32 range_max
float32[] ranges
float32[] intensities
""",
    _HEADER_DEF,
    _TIME_DEF,
)

POSE_STAMPED_TYPE = "geometry_msgs/msg/PoseStamped"
POSE_STAMPED_DEF = _msgdef(
    "std_msgs/Header header\ngeometry_msgs/Pose pose",
    _HEADER_DEF,
    _TIME_DEF,
    "MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation",
    "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z",
    _QUATERNION_DEF,
)

TF_MESSAGE_TYPE = "tf2_msgs/msg/TFMessage"
TF_MESSAGE_DEF = _msgdef(
    "geometry_msgs/TransformStamped[] transforms",
    "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\n"
    "geometry_msgs/Transform transform",
    _HEADER_DEF,
    _TIME_DEF,
    "MSG: geometry_msgs/Transform\ngeometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation",
    "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z",
    _QUATERNION_DEF,
)

JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
JOINT_STATE_DEF = _msgdef(
    "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort",
    _HEADER_DEF,
    _TIME_DEF,
)

# --- JSON schemas of the lasercal topics ---------------------------------------------

_NUMBER_ARRAY = {"type": "array", "items": {"type": "number"}}
_GEOMETRY_SCHEMA = {
    "type": "object",
    "properties": {
        name: {"type": "integer" if field.type == "int" else "number"}
        for name, field in ScanGeometry.__dataclass_fields__.items()
    },
}

JSON_SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    TOPIC_META: (
        "lasercal.Meta",
        {"type": "object", "description": "Resolved configuration, device identities, versions"},
    ),
    TOPIC_EVENT: (
        "lasercal.Event",
        {
            "type": "object",
            "properties": {
                "kind": {
                    "type": "string",
                    "description": "one of " + ", ".join(k.value for k in EventKind) + ", or another kind",
                },
                "host_time_s": {"type": "number"},
                "index": {"type": ["integer", "null"], "description": "waypoint index"},
                "tcp_pose": _NUMBER_ARRAY,
            },
            "required": ["kind", "host_time_s"],
        },
    ),
    TOPIC_SCAN_INFO: (
        "lasercal.ScanInfo",
        {
            "type": "object",
            "properties": {
                "sequence": {"type": "integer"},
                "host_time_s": {"type": "number"},
                "device_time_s": {"type": "number"},
                "geometry": _GEOMETRY_SCHEMA,
                "raw_ranges_mm": {"type": "array", "items": {"type": "integer"}},
                "intensities": {"type": "array", "items": {"type": "integer"}},
                "ranges_m_f64le_b64": {"type": "string"},
            },
            "required": ["sequence", "host_time_s", "device_time_s", "geometry"],
        },
    ),
    TOPIC_TCP_POSE_EXACT: (
        "lasercal.TcpPose",
        {
            "type": "object",
            "properties": {"host_time_s": {"type": "number"}, "pose": _NUMBER_ARRAY},
            "required": ["host_time_s", "pose"],
        },
    ),
    TOPIC_JOINT_STATES_EXACT: (
        "lasercal.JointState",
        {
            "type": "object",
            "properties": {"host_time_s": {"type": "number"}, "q_rad": _NUMBER_ARRAY},
            "required": ["host_time_s", "q_rad"],
        },
    ),
}

# --- times -----------------------------------------------------------------------------


def time_ns(host_time_s: float) -> int:
    """MCAP log time (integer nanoseconds, never negative) for a host time in seconds."""
    return max(0, round(host_time_s * 1e9))


def ros_stamp(host_time_s: float) -> dict[str, int]:
    """``builtin_interfaces/Time`` for a host time (UNIX seconds expected)."""
    sec, nanosec = divmod(time_ns(host_time_s), 1_000_000_000)
    return {"sec": sec, "nanosec": nanosec}


# --- scans: what the ROS message carries and the rules to get the rest back --------------


def ranges_m_from_raw_mm(raw_ranges_mm: ArrayLike, geometry: ScanGeometry) -> NDArray[np.float64]:
    """The product's ``LaserScan.ranges_m`` rule: ``raw / 1000.0`` where DMIN <= raw <= DMAX
    (in whole millimetres), NaN elsewhere (error codes, out-of-range values)."""
    raw = np.asarray(raw_ranges_mm, dtype=np.int64)
    min_mm = round(geometry.min_range_m * 1000.0)
    max_mm = round(geometry.max_range_m * 1000.0)
    valid = (raw >= min_mm) & (raw <= max_mm)
    return np.where(valid, raw / 1000.0, np.nan)


def raw_mm_to_ros_ranges(raw_ranges_mm: ArrayLike) -> NDArray[np.float32]:
    """``LaserScan.ranges`` in metres carrying every raw value (error codes too).

    Error codes (< DMIN) land below ``range_min`` and overflow values above ``range_max``,
    so ROS tools treat them as invalid, as REP 117 asks; the raw integer comes back with
    ``ros_ranges_to_raw_mm``.
    """
    return (np.asarray(raw_ranges_mm, dtype=np.int64) / 1000.0).astype(np.float32)


def ros_ranges_to_raw_mm(ranges: ArrayLike) -> NDArray[np.int64]:
    """Inverse of ``raw_mm_to_ros_ranges`` (exact for 0 <= raw < 2**24)."""
    return np.rint(np.asarray(ranges, dtype=np.float32).astype(np.float64) * 1000.0).astype(np.int64)


def encode_float64_array(values: ArrayLike) -> str:
    """Base64 of little-endian float64 bytes: exact, NaN included, JSON-safe."""
    return base64.b64encode(np.asarray(values, dtype="<f8").tobytes()).decode("ascii")


def decode_float64_array(text: str) -> NDArray[np.float64]:
    """Inverse of ``encode_float64_array``."""
    return np.frombuffer(base64.b64decode(text), dtype="<f8").astype(np.float64)


def geometry_to_dict(geometry: ScanGeometry) -> dict[str, Any]:
    """A ScanGeometry as plain JSON values (floats keep full precision)."""
    return dataclasses.asdict(geometry)


def geometry_from_dict(values: dict[str, Any]) -> ScanGeometry:
    """Inverse of ``geometry_to_dict``."""
    return ScanGeometry(**{name: values[name] for name in ScanGeometry.__dataclass_fields__})


# --- JSON ----------------------------------------------------------------------------------


def to_jsonable(value: Any) -> Any:
    """Plain JSON values from dicts, sequences, numpy values, dataclasses, pydantic models,
    enums and paths. Non-finite floats become ``null`` (strict JSON has no NaN)."""
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [to_jsonable(v) for v in (value.tolist() if isinstance(value, np.ndarray) else value)]
    if isinstance(value, np.generic):
        return to_jsonable(value.item())
    if isinstance(value, enum.Enum):
        return to_jsonable(value.value)
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return to_jsonable({f.name: getattr(value, f.name) for f in dataclasses.fields(value)})
    if hasattr(value, "model_dump"):
        return to_jsonable(value.model_dump(mode="json"))
    if isinstance(value, PurePath):
        return str(value)
    raise TypeError(f"cannot record a value of type {type(value).__name__} as JSON: {value!r}")


def dump_json(document: Any) -> bytes:
    """Compact strict JSON bytes of a document (see ``to_jsonable``)."""
    return json.dumps(to_jsonable(document), separators=(",", ":"), allow_nan=False).encode()
