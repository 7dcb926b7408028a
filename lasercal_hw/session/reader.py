"""Read a ``session.mcap`` back into the values the live run saw, bit for bit.

A file whose writer was killed has no summary or footer and may end inside a record:
``read_session`` reads every complete record, drops the incomplete tail and reports it
with ``SessionRecording.truncated``. A chunk whose CRC fails (a flipped bit on disk) is
skipped on its own: the records around it are kept and ``SessionRecording.damaged``
says what was lost (bytes and the time span of its messages). Layout:
``lasercal_hw.session.format``.
"""

from __future__ import annotations

import io
import json
import logging
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.records import Channel, McapRecord, Message, Schema
from mcap.stream_reader import MAGIC_SIZE, StreamReader
from mcap_ros2.decoder import DecoderFactory

from lasercal_hw.config import DEFAULT_SCANNER_NAME
from lasercal_hw.errors import ConfigError
from lasercal_hw.models import FloatArray, LaserScan, ScanGeometry
from lasercal_hw.session.format import (
    META_JOB_SCANNERS,
    META_SCANNER_NAME,
    TOPIC_EVENT,
    TOPIC_JOINT_STATES_EXACT,
    TOPIC_META,
    TOPIC_SCAN,
    TOPIC_SCAN_INFO,
    TOPIC_TCP_POSE_EXACT,
    EventKind,
    decode_float64_array,
    geometry_from_dict,
    ranges_m_from_raw_mm,
    ros_ranges_to_raw_mm,
    scanner_of_topic,
)

logger = logging.getLogger(__name__)

_MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEADER = struct.Struct("<BQ")


class McapRecords:
    """The complete records of an MCAP file in file order, tolerant of a killed writer and
    of damaged chunks.

    ``truncated`` is True when the file has no footer (the writer did not close it) or ends
    in an incomplete or corrupt record; ``truncation_reason`` says which. ``damaged`` lists
    the chunks skipped because they failed their CRC or did not decode (after iterating).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            data = self.path.read_bytes()
        except FileNotFoundError as exc:
            raise ConfigError(f"session file {self.path} not found; check the path") from exc
        except IsADirectoryError as exc:
            raise ConfigError(f"{self.path} is a directory; pass the session.mcap file inside it") from exc
        except OSError as exc:
            raise ConfigError(f"cannot read session file {self.path}: {exc.strerror}") from exc
        if len(data) < MAGIC_SIZE and _MAGIC.startswith(data):
            data = b""
        elif not data.startswith(_MAGIC):
            raise ConfigError(f"{self.path} is not an MCAP file (wrong magic bytes); pass a session.mcap")
        self._spans, self.truncation_reason = _record_spans(data)
        self.truncated = self.truncation_reason is not None
        self.damaged: list[str] = []
        self._data = data

    def __iter__(self) -> Iterator[McapRecord]:
        """Each top-level record on its own, so one bad chunk costs only its contents."""
        self.damaged = []
        for offset, end in self._spans:
            record = self._data[offset:end]
            try:
                inner = list(_records_of(record))
            except (McapError, ValueError, struct.error, RuntimeError) as exc:
                cause = exc or type(exc).__name__
                if record[0] != Opcode.CHUNK:
                    self.truncated = True
                    self.truncation_reason = f"unreadable record at offset {offset}: {cause}"
                    return
                self.damaged.append(_chunk_loss(record, offset, exc))
                continue
            yield from inner


def _records_of(record: bytes) -> Iterator[McapRecord]:
    """The records one top-level record holds (a chunk's contents, CRC checked)."""
    reader = StreamReader(io.BytesIO(record), skip_magic=True, validate_crcs=True)
    try:
        yield from reader.records
    except EndOfFile:
        return


_CHUNK_TIMES = struct.Struct("<QQ")


def _chunk_loss(record: bytes, offset: int, cause: BaseException) -> str:
    """What skipping a damaged chunk lost, in words (its size and message time span)."""
    start_ns, end_ns = _CHUNK_TIMES.unpack_from(record, _RECORD_HEADER.size)
    span = ""
    if 0 < start_ns <= end_ns < 1 << 62:  # the header itself may be the damaged part
        span = (f", {(end_ns - start_ns) / 1e9:.1f} s of messages, {start_ns / 1e9:.3f} to "
                f"{end_ns / 1e9:.3f} s")
    return f"chunk at byte {offset} ({len(record)} bytes{span}): {cause or type(cause).__name__}"


def _record_spans(data: bytes) -> tuple[list[tuple[int, int]], str | None]:
    """(start, end) of every whole record of ``data`` after the magic, and why the rest is
    missing (None for a properly closed file)."""
    spans: list[tuple[int, int]] = []
    if not data:
        return spans, "the file is empty (writer killed before the header was written)"
    offset = MAGIC_SIZE
    while True:
        if offset + _RECORD_HEADER.size > len(data):
            return spans, "no footer: the writer did not close the file"
        opcode, length = _RECORD_HEADER.unpack_from(data, offset)
        if opcode == 0:
            return spans, f"zero bytes at offset {offset} (unfinished write)"
        end = offset + _RECORD_HEADER.size + length
        if end > len(data):
            return spans, f"incomplete record at offset {offset} (writer killed mid-write)"
        spans.append((offset, end))
        if opcode == Opcode.FOOTER:
            closed = data[end : end + MAGIC_SIZE] == _MAGIC
            return spans, None if closed else "footer without the closing magic bytes"
        offset = end


@dataclass(frozen=True)
class TimedPose:
    """A TCP pose (UR vector, base frame) at a host time."""

    host_time_s: float
    pose: FloatArray


@dataclass(frozen=True)
class TimedJoints:
    """Joint positions (rad) at a host time."""

    host_time_s: float
    q_rad: FloatArray


@dataclass(frozen=True)
class DwellWindow:
    """One waypoint's dwell: when it started and ended and where the TCP was.

    ``tcp_pose`` is the pose recorded with ``dwell_start`` (or with ``dwell_end`` when the
    start carried none); ``end_s`` is None when the run stopped during the dwell.
    ``scan_sequences`` are the scans the live run averaged, when ``dwell_end`` listed them.
    """

    index: int
    start_s: float | None
    end_s: float | None
    tcp_pose: FloatArray | None
    tcp_pose_end: FloatArray | None
    scan_sequences: tuple[int, ...] | None = None

    @property
    def complete(self) -> bool:
        """True when both the start and the end of the dwell were recorded."""
        return self.start_s is not None and self.end_s is not None


@dataclass
class SessionRecording:
    """Everything a ``session.mcap`` holds, as the product's value types."""

    path: Path
    metas: list[dict[str, Any]] = field(default_factory=list)
    scans: list[LaserScan] = field(default_factory=list)
    #: The scans of a cell's other scanners, by name, recorded while they watched this run's
    #: waypoints (``/scan/NAME``; docs/cell.md); ``scans`` holds the run's own scanner's.
    scans_by_scanner: dict[str, list[LaserScan]] = field(default_factory=dict)
    tcp_poses: list[TimedPose] = field(default_factory=list)
    joint_states: list[TimedJoints] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    truncated: bool = False
    truncation_reason: str | None = None
    damaged: list[str] = field(default_factory=list)
    """Damaged chunks skipped while reading, each with what it lost."""
    #: The scanner whose run this is the view of (``for_scanner`` of a job recording); None: the file.
    view_of: str | None = None

    @property
    def is_job_recording(self) -> bool:
        """True for a cell job's one recording (every scanner's run; docs/recorder.md), not a view."""
        return self.view_of is None and any(
            META_JOB_SCANNERS in document and META_SCANNER_NAME not in document for document in self.metas
        )

    @property
    def scanner_names(self) -> list[str]:
        """The scanners whose runs the recording holds: a job recording's that have started, in
        order; a one-scanner recording's one (its meta's ``scanner_name``, else ``default``)."""
        if self.view_of is not None:
            return [self.view_of]
        if not self.is_job_recording:
            return [str(self.meta.get(META_SCANNER_NAME) or DEFAULT_SCANNER_NAME)]
        names: list[str] = []
        for document in self.metas:
            name = document.get(META_SCANNER_NAME)
            if name is not None and str(name) not in names:
                names.append(str(name))
        return names

    def for_scanner(self, name: str | None) -> SessionRecording:
        """Scanner ``name``'s run as its own one-scanner recording would hold it: of a job
        recording, its meta documents and events (and the untagged ones), its scans as ``scans``
        and the other scanners' as ``scans_by_scanner``, every TCP pose and joint state; a
        one-scanner recording is its own view (``name`` None or its scanner's). The one way a
        reader selects a scanner; a scanner the file does not hold is a one-line ``ConfigError``
        naming those it holds."""
        names = self.scanner_names
        if not self.is_job_recording:
            if name is None or name in names:
                return self
            raise ConfigError(
                f"{self.path} is the recording of scanner {names[0]!r} alone, not of {name!r}; "
                f"leave out the scanner name, or pass {names[0]!r}"
            )
        held = ", ".join(names) if names else "none yet (no scanner's run has started)"
        if name is None:
            if len(names) != 1:
                raise ConfigError(
                    f"{self.path} is a cell job's recording of several scanners ({held}); name the one to "
                    "read with --scanner NAME"
                )
            name = names[0]
        if name not in names:
            raise ConfigError(f"{self.path} holds no run of scanner {name!r}; the scanners it holds: {held}")

        def mine(document: dict[str, Any]) -> bool:
            return document.get(META_SCANNER_NAME) in (None, name)

        return SessionRecording(
            path=self.path,
            metas=[document for document in self.metas if mine(document)],
            scans=self.scans_by_scanner.get(name, []),
            scans_by_scanner={other: s for other, s in self.scans_by_scanner.items() if other != name},
            tcp_poses=self.tcp_poses,
            joint_states=self.joint_states,
            events=[event for event in self.events if mine(event)],
            truncated=self.truncated,
            truncation_reason=self.truncation_reason,
            damaged=self.damaged,
            view_of=name,
        )

    @property
    def meta(self) -> dict[str, Any]:
        """All ``/lasercal/meta`` documents merged in order (later keys win)."""
        merged: dict[str, Any] = {}
        for document in self.metas:
            merged.update(document)
        return merged

    def events_of(self, kind: str) -> list[dict[str, Any]]:
        """Events of one kind, in recording order."""
        return [event for event in self.events if event.get("kind") == kind]

    def dwell_windows(self) -> list[DwellWindow]:
        """One window per waypoint index, sorted by index.

        When a waypoint was dwelt at more than once (a resumed run redoing it), the last
        complete dwell wins; a dwell that never ended counts only if none completed.
        """
        best: dict[int, DwellWindow] = {}
        open_windows: dict[int, DwellWindow] = {}
        for event in self.events:
            kind = event.get("kind")
            if kind not in (EventKind.DWELL_START, EventKind.DWELL_END):
                continue
            index = int(event["index"])
            pose = _pose_or_none(event.get("tcp_pose"))
            if kind == EventKind.DWELL_START:
                window = DwellWindow(index, event["host_time_s"], None, pose, None)
                open_windows[index] = window
                if index not in best or not best[index].complete:
                    best[index] = window
            else:
                started = open_windows.pop(index, None)
                start_s = started.start_s if started else None
                start_pose = started.tcp_pose if started else None
                sequences = event.get("scan_sequences")
                best[index] = DwellWindow(
                    index,
                    start_s,
                    event["host_time_s"],
                    start_pose if start_pose is not None else pose,
                    pose,
                    None if sequences is None else tuple(int(k) for k in sequences),
                )
        return [best[index] for index in sorted(best)]

    def scans_between(self, start_s: float, end_s: float) -> list[LaserScan]:
        """Scans whose host time lies in ``[start_s, end_s]``."""
        return [scan for scan in self.scans if start_s <= scan.host_time_s <= end_s]

    def dwell_scans(self, window: DwellWindow) -> list[LaserScan]:
        """The scans of a dwell: exactly those the live run averaged when ``dwell_end``
        listed their ``scan_sequences`` (so a replay averages the same scans), otherwise
        those recorded between the dwell's start and end. Empty for an incomplete dwell."""
        if window.scan_sequences is not None:
            # Sequence numbers restart with the scanner: take the latest one up to the end.
            wanted = set(window.scan_sequences)
            chosen: dict[int, LaserScan] = {}
            for scan in self.scans:
                if scan.sequence in wanted and (window.end_s is None or scan.host_time_s <= window.end_s):
                    chosen[scan.sequence] = scan
            return [chosen[k] for k in window.scan_sequences if k in chosen]
        if not window.complete:
            return []
        return self.scans_between(window.start_s, window.end_s)


def _pose_or_none(values: Any) -> FloatArray | None:
    return None if values is None else np.asarray(values, dtype=np.float64)


def read_session(path: str | Path, *, include_scans: bool = True) -> SessionRecording:
    """Read a session recording; a file cut short by a crash gives what is complete and
    ``truncated=True``. ``include_scans=False`` skips decoding scans (faster)."""
    records = McapRecords(path)
    recording = SessionRecording(path=Path(path))
    decoders = DecoderFactory()
    # Schemas and channels first, from anywhere in the file: a closed file repeats them in
    # its summary, so messages after a damaged chunk that defined them still decode.
    every = list(records)
    schemas = {record.id: record for record in every if isinstance(record, Schema)}
    channels = {
        record.id: (record.topic, schemas.get(record.schema_id))
        for record in every
        if isinstance(record, Channel)
    }
    pending_scans: dict[str | None, tuple[int, Any]] = {}  # by scanner (None: the run's own)
    for record in every:
        if isinstance(record, Message) and record.channel_id in channels:
            topic, schema = channels[record.channel_id]
            is_scan, scanner = scanner_of_topic(topic, TOPIC_SCAN)
            is_info, info_scanner = scanner_of_topic(topic, TOPIC_SCAN_INFO)
            if is_scan and include_scans:
                arrays = _laser_scan_arrays(record.data)
                if arrays is None:
                    decoder = decoders.decoder_for("cdr", schema)
                    message = decoder(record.data) if decoder is not None else None
                    arrays = (
                        None
                        if message is None
                        else _LaserScanArrays(
                            message.ranges, message.intensities, message.angle_min, message.angle_increment
                        )
                    )
                if arrays is not None:
                    pending_scans[scanner] = (record.sequence, arrays)
            elif is_info and include_scans:
                pending_scan = pending_scans.pop(info_scanner, None)
                if pending_scan is not None and pending_scan[0] == record.sequence:
                    scan = _scan_from(_json(record), pending_scan[1], Path(path))
                    if info_scanner is None:
                        recording.scans.append(scan)
                    else:
                        recording.scans_by_scanner.setdefault(info_scanner, []).append(scan)
                else:
                    logger.warning("%s: scan %d has no LaserScan message; skipped", path, record.sequence)
            elif topic == TOPIC_TCP_POSE_EXACT:
                document = _json(record)
                recording.tcp_poses.append(
                    TimedPose(document["host_time_s"], np.asarray(document["pose"], dtype=np.float64))
                )
            elif topic == TOPIC_JOINT_STATES_EXACT:
                document = _json(record)
                recording.joint_states.append(
                    TimedJoints(document["host_time_s"], np.asarray(document["q_rad"], dtype=np.float64))
                )
            elif topic == TOPIC_EVENT:
                recording.events.append(_json(record))
            elif topic == TOPIC_META:
                recording.metas.append(_json(record))
    recording.truncated = records.truncated
    recording.truncation_reason = records.truncation_reason
    recording.damaged = list(records.damaged)
    for loss in recording.damaged:
        logger.warning("%s: a damaged chunk was skipped and the rest kept; lost the %s", path, loss)
    if recording.truncated:
        logger.warning("%s is truncated (%s); read what is complete", path, records.truncation_reason)
    return recording


@dataclass(frozen=True)
class _LaserScanArrays:
    """What the reader takes from a ``sensor_msgs/msg/LaserScan``."""

    ranges: Any
    intensities: Any
    angle_min_rad: float
    angle_increment_rad: float


#: Agreement asked of a LaserScan's angles and its scan_info's beam layout (float32 of ~2 rad).
_ANGLE_TOLERANCE_RAD = 1e-6


def _laser_scan_arrays(data: bytes) -> _LaserScanArrays | None:
    """``ranges``, ``intensities`` and the angles of a plain-CDR ``sensor_msgs/msg/LaserScan``
    read with numpy (mcap_ros2's decoder reads them one float at a time, 5x slower); None when
    the bytes are not the layout expected, and the caller falls back to that decoder."""
    if len(data) < 16 or data[0] != 0 or data[1] not in (0, 1):
        return None
    order = "<" if data[1] == 1 else ">"
    uint32 = struct.Struct(order + "I")
    frame_id_end = 16 + uint32.unpack_from(data, 12)[0]  # after stamp and the string length
    offset = 4 + -(-(frame_id_end - 4) // 4) * 4  # align 4: angle_min, angle_max, angle_increment, ...
    if offset + 7 * 4 > len(data):
        return None
    angle_min, _, angle_increment = struct.unpack_from(order + "3f", data, offset)
    offset += 7 * 4  # skip the seven float32 fields
    arrays = []
    for _ in range(2):
        if offset + 4 > len(data):
            return None
        count = uint32.unpack_from(data, offset)[0]
        offset += 4
        if offset + 4 * count > len(data):
            return None
        arrays.append(np.frombuffer(data, dtype=order + "f4", count=count, offset=offset))
        offset += 4 * count
    if offset != len(data):
        return None
    return _LaserScanArrays(arrays[0], arrays[1], angle_min, angle_increment)


def _check_angles(geometry: ScanGeometry, arrays: _LaserScanArrays, sequence: object, path: Path) -> None:
    """Refuse a scan whose LaserScan angles disagree with the beam layout of its scan_info
    (the angles every fit uses): a replay must not place the beams where they were not."""
    first, increment = geometry.angle_min_rad, geometry.angle_increment_rad
    if (
        abs(arrays.angle_min_rad - first) > _ANGLE_TOLERANCE_RAD
        or abs(arrays.angle_increment_rad - increment) > _ANGLE_TOLERANCE_RAD
    ):
        said = np.degrees([arrays.angle_min_rad, arrays.angle_increment_rad])
        layout = f"first step {geometry.first_step}, cluster {geometry.cluster}"
        raise ConfigError(
            f"{path}: scan {sequence}'s LaserScan says angle_min {said[0]:.4f}, increment {said[1]:.4f} deg, "
            f"but its scan_info beam layout ({layout}) gives {np.degrees(first):.4f}, "
            f"{np.degrees(increment):.4f} deg: the recording contradicts itself (edited, or written by "
            "another tool?) and cannot be replayed; record the run again"
        )


def _json(record: Message) -> Any:
    return json.loads(record.data)


def _scan_from(info: dict[str, Any], arrays: _LaserScanArrays, path: Path) -> LaserScan:
    geometry = geometry_from_dict(info["geometry"])
    _check_angles(geometry, arrays, info.get("sequence"), path)
    if "raw_ranges_mm" in info:
        raw_mm = np.asarray(info["raw_ranges_mm"], dtype=np.int64)
    else:
        raw_mm = ros_ranges_to_raw_mm(arrays.ranges)
    intensities = None
    if "intensities" in info:
        intensities = np.asarray(info["intensities"], dtype=np.int64)
    elif info.get("has_intensities", False):
        intensities = np.asarray(arrays.intensities, dtype=np.float32).astype(np.int64)
    if "ranges_m_f64le_b64" in info:
        ranges_m = decode_float64_array(info["ranges_m_f64le_b64"])
    else:
        ranges_m = ranges_m_from_raw_mm(raw_mm, geometry)
    return LaserScan(
        sequence=info["sequence"],
        geometry=geometry,
        ranges_m=ranges_m,
        raw_ranges_mm=raw_mm,
        intensities=intensities,
        device_time_s=info["device_time_s"],
        host_time_s=info["host_time_s"],
    )
