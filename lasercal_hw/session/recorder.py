"""Record a calibration run into ``session.mcap`` while it runs, crash-safe.

Every ``write_*`` call ends with the MCAP writer's ``flush()``: the records of that call
form one complete (zstd-compressed) chunk that is in the operating system's hands when the
call returns, so a process killed by SIGKILL or Ctrl-C leaves a file that
``lasercal_hw.session.reader.read_session`` reads up to the last call. Events are also
``fsync``-ed, so the run's milestones survive a power cut too. ``close()`` writes the
MCAP summary and footer (indexes for fast seeking in Foxglove).

Resume: ``SessionRecorder.resume(path)`` keeps the interrupted file as
``<stem>.interrupted-<k>.mcap``, writes a new file that starts with a byte-exact copy of
every complete message of the old one, and continues recording into it. See
docs/recorder.md.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import threading
import time
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import numpy as np
from mcap.records import Channel, Message, Metadata, Schema
from mcap.well_known import MessageEncoding, Profile, SchemaEncoding
from mcap.writer import CompressionType, Writer
from mcap_ros2._dynamic import serialize_dynamic  # private (no public encoder); version pinned in pyproject
from numpy.typing import ArrayLike

from lasercal_hw import __version__
from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import matrix_to_quat, rotvec_to_quat
from lasercal_hw.models import LaserScan
from lasercal_hw.session.format import (
    FORMAT_NAME,
    FORMAT_VERSION,
    FRAME_BASE,
    JOINT_STATE_DEF,
    JOINT_STATE_TYPE,
    JSON_SCHEMAS,
    LASER_SCAN_DEF,
    LASER_SCAN_TYPE,
    META_SCANNER_NAME,
    POSE_STAMPED_DEF,
    POSE_STAMPED_TYPE,
    TF_MESSAGE_DEF,
    TF_MESSAGE_TYPE,
    TOPIC_EVENT,
    TOPIC_JOINT_STATES,
    TOPIC_JOINT_STATES_EXACT,
    TOPIC_META,
    TOPIC_SCAN,
    TOPIC_SCAN_INFO,
    TOPIC_TCP_POSE,
    TOPIC_TCP_POSE_EXACT,
    TOPIC_TF_STATIC,
    UR_JOINT_NAMES,
    EventKind,
    dump_json,
    encode_float64_array,
    geometry_to_dict,
    ranges_m_from_raw_mm,
    raw_mm_to_ros_ranges,
    ros_ranges_to_raw_mm,
    ros_stamp,
    scan_topics,
    time_ns,
)
from lasercal_hw.session.reader import McapRecords, SessionRecording, read_session

logger = logging.getLogger(__name__)

_ROS_TOPICS = {
    TOPIC_SCAN: (LASER_SCAN_TYPE, LASER_SCAN_DEF),
    TOPIC_TCP_POSE: (POSE_STAMPED_TYPE, POSE_STAMPED_DEF),
    TOPIC_JOINT_STATES: (JOINT_STATE_TYPE, JOINT_STATE_DEF),
    TOPIC_TF_STATIC: (TF_MESSAGE_TYPE, TF_MESSAGE_DEF),
}
_METADATA_NAME = "lasercal_session"


class SessionRecorder:
    """Writes one run's ``session.mcap`` (see the module docstring and docs/recorder.md).

    ``meta`` (resolved config, device identities, ...) is written first on
    ``/lasercal/meta``; pass ``meta=None`` to write it later with ``write_meta``. An
    existing file is never overwritten unless ``overwrite=True``. Thread-safe: a scanner
    thread may call ``write_scan`` while the sequencer writes events.
    """

    def __init__(self, path: str | Path, meta: dict[str, Any] | None, *, overwrite: bool = False) -> None:
        self.path = Path(path)
        if self.path.exists() and not overwrite:
            raise ConfigError(
                f"session file {self.path} already exists: resume that run from its recording, "
                "or choose another output path"
            )
        self.previous: SessionRecording | None = None
        self._lock = threading.Lock()
        self._closed = False
        try:
            self._file: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - lives until close()
        except OSError as exc:
            raise ConfigError(f"cannot create session file {self.path}: {exc.strerror}") from exc
        self._writer = Writer(self._file, compression=CompressionType.ZSTD)
        self._writer.start(profile=Profile.ROS2, library=f"lasercal/{__version__}")
        self._writer.add_metadata(
            _METADATA_NAME,
            {"format": FORMAT_NAME, "format_version": str(FORMAT_VERSION), "lasercal_version": __version__},
        )
        self._schema_ids: dict[tuple[str, str, bytes], int] = {}
        self._channel_ids: dict[str, int] = {}
        self._encoders: dict[str, Any] = {}
        self._sequences: dict[str, int] = {}
        self._sync()
        if meta is not None:
            self.write_meta(meta)

    # --- public API ------------------------------------------------------------------

    @classmethod
    def resume(
        cls, path: str | Path, meta: dict[str, Any] | None = None, *, host_time_s: float | None = None
    ) -> SessionRecorder:
        """Continue an interrupted recording at ``path``.

        The old file is kept as ``<stem>.interrupted-<k>.mcap``; ``path`` becomes a new file
        holding a byte-exact copy of every complete message of the old one, a ``resume``
        event, ``meta`` (if given) and whatever is recorded next. At every moment ``path``
        holds a readable session. ``recorder.previous`` is what the old file held, so the
        caller can skip the waypoints already done. ``host_time_s`` stamps the ``resume``
        event (default: now, ``time.time()``).
        """
        path = Path(path)
        previous = read_session(path)
        backup = _free_backup_path(path)
        _link_or_copy(path, backup)
        staging = path.with_name(path.name + ".resume-tmp")
        recorder = cls(staging, None, overwrite=True)
        try:
            copied = recorder.copy_from(backup)
            recorder.previous = previous
            recorder.write_event(
                time.time() if host_time_s is None else host_time_s,
                EventKind.RESUME,
                previous_file=backup.name,
                previous_truncated=previous.truncated,
                copied_messages=copied,
            )
            if meta is not None:
                recorder.write_meta(meta)
            os.replace(staging, path)
        except BaseException:
            recorder.close()
            staging.unlink(missing_ok=True)
            raise
        recorder.path = path
        logger.info("resuming %s: copied %d messages, old file kept as %s", path, copied, backup)
        return recorder

    def write_meta(self, meta: dict[str, Any], host_time_s: float | None = None) -> None:
        """Record the resolved configuration, device identities and versions (stamped
        ``host_time_s``, default now); ``SessionRecording.meta`` merges them in order."""
        self._write_json(TOPIC_META, time.time() if host_time_s is None else host_time_s, meta, sync=True)

    def write_scan(self, scan: LaserScan, scanner: str | None = None) -> None:
        """Record one scan: ``/scan`` (LaserScan) plus ``/lasercal/scan_info``; a cell's other
        scanner ``scanner`` (watching this run's waypoints) on its own topics (``scan_topics``)."""
        scan_topic, info_topic, frame = scan_topics(scanner)
        geometry = scan.geometry
        raw_mm = np.asarray(scan.raw_ranges_mm, dtype=np.int64)
        ros_ranges = raw_mm_to_ros_ranges(raw_mm)
        info: dict[str, Any] = {
            "sequence": int(scan.sequence),
            "host_time_s": float(scan.host_time_s),
            "device_time_s": float(scan.device_time_s),
            "geometry": geometry_to_dict(geometry),
            "has_intensities": scan.intensities is not None,
        }
        if not np.array_equal(ros_ranges_to_raw_mm(ros_ranges), raw_mm):
            info["raw_ranges_mm"] = raw_mm
        ros_intensities: list[float] = []
        if scan.intensities is not None:
            intensities = np.asarray(scan.intensities, dtype=np.int64)
            as_float32 = intensities.astype(np.float32)
            ros_intensities = as_float32.tolist()
            if not np.array_equal(as_float32.astype(np.int64), intensities):
                info["intensities"] = intensities  # beyond float32's exact integers
        expected_m = ranges_m_from_raw_mm(raw_mm, geometry)
        if not np.array_equal(np.asarray(scan.ranges_m, dtype=np.float64), expected_m, equal_nan=True):
            info["ranges_m_f64le_b64"] = encode_float64_array(scan.ranges_m)
        angles = geometry.angles_rad()
        cluster = max(geometry.cluster, 1)
        message = {
            "header": {"stamp": ros_stamp(scan.host_time_s), "frame_id": frame},
            "angle_min": float(angles[0]) if angles.size else 0.0,
            "angle_max": float(angles[-1]) if angles.size else 0.0,
            "angle_increment": geometry.angle_increment_rad,
            "time_increment": cluster * geometry.scan_period_s / geometry.steps_per_revolution,
            "scan_time": geometry.scan_period_s,
            "range_min": geometry.min_range_m,
            "range_max": geometry.max_range_m,
            "ranges": ros_ranges.tolist(),
            "intensities": ros_intensities,
        }
        sequence = int(scan.sequence) & 0xFFFFFFFF
        with self._lock:
            self._add_ros(scan_topic, scan.host_time_s, message, sequence, kind=TOPIC_SCAN)
            self._add_json(info_topic, scan.host_time_s, info, sequence, kind=TOPIC_SCAN_INFO)
            self._sync()

    def write_tcp_pose(self, host_time_s: float, pose: ArrayLike) -> None:
        """Record the actual TCP pose (UR vector ``[x, y, z, rx, ry, rz]``, base frame)."""
        pose = np.asarray(pose, dtype=np.float64).reshape(6)
        qx, qy, qz, qw = rotvec_to_quat(pose[3:6]).tolist()
        message = {
            "header": {"stamp": ros_stamp(host_time_s), "frame_id": FRAME_BASE},
            "pose": {
                "position": {"x": pose[0], "y": pose[1], "z": pose[2]},
                "orientation": {"x": qx, "y": qy, "z": qz, "w": qw},
            },
        }
        with self._lock:
            self._add_ros(TOPIC_TCP_POSE, host_time_s, message)
            self._add_json(TOPIC_TCP_POSE_EXACT, host_time_s, {"host_time_s": host_time_s, "pose": pose})
            self._sync()

    def write_joint_state(self, host_time_s: float, q_rad: ArrayLike) -> None:
        """Record the actual joint positions (rad) under the UR joint names."""
        q = np.asarray(q_rad, dtype=np.float64).reshape(-1)
        names = list(UR_JOINT_NAMES)
        if q.size != len(names):
            names = [f"joint_{i}" for i in range(q.size)]
        message = {
            "header": {"stamp": ros_stamp(host_time_s), "frame_id": ""},
            "name": names,
            "position": q.tolist(),
            "velocity": [],
            "effort": [],
        }
        with self._lock:
            self._add_ros(TOPIC_JOINT_STATES, host_time_s, message)
            self._add_json(TOPIC_JOINT_STATES_EXACT, host_time_s, {"host_time_s": host_time_s, "q_rad": q})
            self._sync()

    def write_frame(self, host_time_s: float, child_frame: str, T_parent_child: ArrayLike) -> None:
        """Record where ``child_frame`` is in the base frame (4x4) on ``/tf_static``, for viewers
        (a cell job's scanner frames: docs/recorder.md); the reader does not use it."""
        T = np.asarray(T_parent_child, dtype=np.float64).reshape(4, 4)
        qx, qy, qz, qw = matrix_to_quat(T[:3, :3]).tolist()
        x, y, z = T[:3, 3].tolist()
        message = {"transforms": [{
            "header": {"stamp": ros_stamp(host_time_s), "frame_id": FRAME_BASE},
            "child_frame_id": child_frame,
            "transform": {"translation": {"x": x, "y": y, "z": z},
                          "rotation": {"x": qx, "y": qy, "z": qz, "w": qw}},
        }]}
        with self._lock:
            self._add_ros(TOPIC_TF_STATIC, host_time_s, message)
            self._sync()

    def write_event(self, host_time_s: float, kind: str, **fields: Any) -> None:
        """Record an event (``EventKind``: dwell_start/dwell_end with ``index`` and
        ``tcp_pose``, observation, abort, fault, resume, run_end) and fsync it."""
        if kind in (EventKind.DWELL_START, EventKind.DWELL_END) and "index" not in fields:
            raise ValueError(f"a {kind} event needs the waypoint 'index'")
        document = {"kind": str(kind), "host_time_s": float(host_time_s), **fields}
        self._write_json(TOPIC_EVENT, host_time_s, document, sync=True)

    def copy_from(self, source: str | Path | McapRecords) -> int:
        """Copy every complete message (and metadata) of the recording ``source`` (a path,
        or its already read records) byte for byte, keeping topics, schemas and times;
        returns the number of messages copied."""
        schemas: dict[int, Schema] = {}
        channels: dict[int, int] = {}
        copied = 0
        with self._lock:
            if self._closed:
                raise RuntimeError(f"session recorder for {self.path} is closed")
            records = source if isinstance(source, McapRecords) else McapRecords(source)
            for record in records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    schema = schemas.get(record.schema_id)
                    if schema is None:
                        continue
                    channels[record.id] = self._channel(
                        record.topic, record.message_encoding, schema.name, schema.encoding, schema.data
                    )
                elif isinstance(record, Message) and record.channel_id in channels:
                    self._writer.add_message(
                        channels[record.channel_id],
                        log_time=record.log_time,
                        data=record.data,
                        publish_time=record.publish_time,
                        sequence=record.sequence,
                    )
                    copied += 1
                elif isinstance(record, Metadata) and record.name != _METADATA_NAME:
                    self._writer.add_metadata(record.name, record.metadata)
            self._sync(durable=True)
        return copied

    def for_scanner(self, name: str) -> ScannerRecorder:
        """What scanner ``name``'s run of a cell job writes to this (the job's one) recording."""
        return ScannerRecorder(self, name)

    def flush(self) -> None:
        """Push everything written so far to the disk (fsync)."""
        with self._lock:
            self._sync(durable=True)

    def close(self) -> None:
        """Write the MCAP summary and footer and close the file; safe to call twice."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._writer.finish()
                self._file.flush()
                os.fsync(self._file.fileno())
            finally:
                self._file.close()

    @property
    def closed(self) -> bool:
        """True after ``close()``."""
        return self._closed

    def __enter__(self) -> SessionRecorder:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # --- internals ---------------------------------------------------------------------

    def _write_json(self, topic: str, host_time_s: float, document: Any, *, sync: bool) -> None:
        with self._lock:
            self._add_json(topic, host_time_s, document)
            self._sync(durable=sync)

    def _add_ros(
        self, topic: str, host_time_s: float, message: dict[str, Any], sequence: int | None = None,
        *, kind: str | None = None,
    ) -> None:
        """``kind``: the topic whose message type ``topic`` carries (default: ``topic``'s own)."""
        datatype, definition = _ROS_TOPICS[kind or topic]
        schema_data = definition.encode()
        channel_id = self._channel(topic, MessageEncoding.CDR, datatype, SchemaEncoding.ROS2, schema_data)
        encoder = self._encoders.get(datatype)
        if encoder is None:
            encoder = serialize_dynamic(datatype, definition)[datatype]
            self._encoders[datatype] = encoder
        self._add(topic, channel_id, host_time_s, encoder(message), sequence)

    def _add_json(
        self, topic: str, host_time_s: float, document: Any, sequence: int | None = None,
        *, kind: str | None = None,
    ) -> None:
        schema_name, schema = JSON_SCHEMAS[kind or topic]
        channel_id = self._channel(
            topic, MessageEncoding.JSON, schema_name, SchemaEncoding.JSONSchema, json.dumps(schema).encode()
        )
        self._add(topic, channel_id, host_time_s, dump_json(document), sequence)

    def _add(
        self, topic: str, channel_id: int, host_time_s: float, data: bytes, sequence: int | None
    ) -> None:
        if self._closed:
            raise RuntimeError(f"session recorder for {self.path} is closed")
        if sequence is None:
            sequence = self._sequences.get(topic, 0)
            self._sequences[topic] = (sequence + 1) & 0xFFFFFFFF
        log_time = time_ns(host_time_s)
        self._writer.add_message(
            channel_id, log_time=log_time, data=data, publish_time=log_time, sequence=sequence
        )

    def _channel(
        self, topic: str, message_encoding: str, schema_name: str, schema_encoding: str, schema_data: bytes
    ) -> int:
        channel_id = self._channel_ids.get(topic)
        if channel_id is None:
            schema_id = self._schema(schema_name, schema_encoding, schema_data)
            channel_id = self._writer.register_channel(topic, message_encoding, schema_id)
            self._channel_ids[topic] = channel_id
        return channel_id

    def _schema(self, name: str, encoding: str, data: bytes) -> int:
        key = (name, encoding, data)
        schema_id = self._schema_ids.get(key)
        if schema_id is None:
            schema_id = self._writer.register_schema(name, encoding, data)
            self._schema_ids[key] = schema_id
        return schema_id

    def _sync(self, durable: bool = False) -> None:
        """Close the chunk in progress and hand it to the OS (and the disk if ``durable``)."""
        self._writer.flush()
        if durable:
            os.fsync(self._file.fileno())


class ScannerRecorder:
    """One scanner's run writing to a cell job's one recording (docs/recorder.md): its scans on
    ``/scan/NAME`` (a watcher's on its own), its meta documents and events tagged
    ``scanner_name``; the TCP poses and joint states as they are. The file is the job's: it is
    closed by whoever opened it, not here."""

    def __init__(self, recorder: SessionRecorder, name: str) -> None:
        self._recorder = recorder
        self.name = name

    @property
    def path(self) -> Path:
        """The job's recording."""
        return self._recorder.path

    def write_meta(self, meta: dict[str, Any], host_time_s: float | None = None) -> None:
        """``SessionRecorder.write_meta``, the document tagged with the scanner."""
        self._recorder.write_meta(meta | {META_SCANNER_NAME: self.name}, host_time_s)

    def write_scan(self, scan: LaserScan, scanner: str | None = None) -> None:
        """This scanner's scan on ``/scan/NAME``; a watcher's (``scanner``) on its own topic."""
        self._recorder.write_scan(scan, scanner or self.name)

    def write_tcp_pose(self, host_time_s: float, pose: ArrayLike) -> None:
        """``SessionRecorder.write_tcp_pose``."""
        self._recorder.write_tcp_pose(host_time_s, pose)

    def write_joint_state(self, host_time_s: float, q_rad: ArrayLike) -> None:
        """``SessionRecorder.write_joint_state``."""
        self._recorder.write_joint_state(host_time_s, q_rad)

    def write_event(self, host_time_s: float, kind: str, **fields: Any) -> None:
        """``SessionRecorder.write_event``, the event tagged with the scanner."""
        self._recorder.write_event(host_time_s, kind, **(fields | {META_SCANNER_NAME: self.name}))


def repair_session(source: str | Path, target: str | Path) -> int:
    """Write the complete part of a (possibly crashed) recording ``source`` as a closed,
    indexed file ``target`` that every MCAP tool opens; returns the messages copied.

    ``source`` is read and checked before ``target`` is created, so a bad source leaves
    nothing behind."""
    if Path(target).exists():
        raise ConfigError(f"repair target {target} already exists; choose a new file name")
    records = McapRecords(source)
    with SessionRecorder(target, None) as recorder:
        return recorder.copy_from(records)


def _free_backup_path(path: Path) -> Path:
    """``<stem>.interrupted-<k><suffix>`` with the first k that does not exist."""
    k = 1
    while True:
        candidate = path.with_name(f"{path.stem}.interrupted-{k}{path.suffix}")
        if not candidate.exists():
            return candidate
        k += 1


def _link_or_copy(source: Path, target: Path) -> None:
    """Keep ``source`` under a second name (hard link, or a copy where links fail)."""
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)
    with contextlib.suppress(OSError):
        fd = os.open(target.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
