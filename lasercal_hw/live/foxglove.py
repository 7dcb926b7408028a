"""The run, live in the Foxglove app: a loopback websocket server (``foxglove-sdk``, the
optional extra ``foxglove``) fed by the engine's events.

Topics (frames ``base``, ``tcp``, ``rod``, ``laser``):

- ``/scan`` (``foxglove.LaserScan``, frame ``laser``): the averaged scan of each waypoint;
- ``/tf`` (``foxglove.FrameTransforms``): base -> tcp (the waypoint's TCP pose), tcp -> rod
  (the rod's origin, z along its axis) and base -> laser (the current estimate of the scanner
  frame: the job's nominal mounting, then the closed-form fit of the centres so far, then
  the solved result);
- ``/lasercal/scene`` (``foxglove.SceneUpdate``): the rod as a cylinder, the fitted circle
  and the measured centres in the scan plane;
- ``/lasercal/log`` (``foxglove.Log``): one line per event.

A cell job (``watch_cell``) shows every scanner in the one scene: scanner NAME's scans on
``/scan/NAME`` in its frame ``laser_NAME`` (as the exports name it), its centres and circle
in that frame, and base -> laser_NAME for every scanner with an estimate; the events of a
cell's run name their scanner (``data["scanner"]``).

``docs/foxglove-layout.json`` arranges these in the app (docs/daemon.md says how to open it).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from lasercal_hw.calibration.initial import linear_initial_pose
from lasercal_hw.calibration.model import rod_lines_in_base
from lasercal_hw.config import DEFAULT_SCANNER_NAME, JobConfig
from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import make_transform, matrix_to_quat, pose_to_matrix
from lasercal_hw.models import FloatArray, RodLine
from lasercal_hw.outputs.exports import scanner_frame
from lasercal_hw.run.cell import CellRunRequest, cell_scanners
from lasercal_hw.run.engine import RunRequest
from lasercal_hw.run.resume import recorded_job
from lasercal_hw.run.waypoints import planned_waypoints
from lasercal_hw.session.reader import read_session

LOOPBACK = "127.0.0.1"
DEFAULT_PORT = 8765
MIN_CENTRES_FOR_ESTIMATE = 5
CIRCLE_SEGMENTS = 48
FRAME_BASE, FRAME_TCP, FRAME_ROD, FRAME_LASER = "base", "tcp", "rod", "laser"
INSTALL_HINT = (
    "the Foxglove live view needs the optional extra foxglove: from lasercal's checkout, "
    ".venv/bin/pip install -e '.[foxglove]'"
)


class EventLike(Protocol):
    """The part of the engine's RunEvent the view reads."""

    kind: str
    message: str
    data: dict[str, Any]


@dataclass(frozen=True)
class RunGeometry:
    """What the view needs besides the events: the waypoints' TCP poses, the rod in the
    TCP frame and, if the job gives one, the nominal scanner mounting."""

    tcp_poses: FloatArray
    rod: RodLine
    nominal_base_laser: FloatArray | None = None

    @classmethod
    def of_job(cls, job: JobConfig, tcp_poses: FloatArray) -> RunGeometry:
        """The geometry of ``job`` visiting ``tcp_poses`` (UR pose vectors, N x 6)."""
        nominal = job.scanner.nominal
        return cls(np.asarray(tcp_poses, dtype=float), job.rod.rod_line(),
                   nominal.matrix() if nominal is not None else None)


    @classmethod
    def of_request(cls, request: RunRequest) -> RunGeometry:
        """The geometry of the run ``request`` asks for (a resumed run's, from its recording)."""
        if request.resume is not None:
            job, tcp_poses = recorded_job(read_session(request.resume))
            return cls.of_job(job, tcp_poses)
        tcp_poses = request.waypoints if request.waypoints is not None else planned_waypoints(request.job)
        return cls.of_job(request.job, tcp_poses)


@dataclass
class ScannerView:
    """One scanner's part of the scene: its geometry, frame, scan topic and what its run has
    shown so far (centres, the latest circle, the estimate of its frame)."""

    geometry: RunGeometry | None
    frame: str
    scan_topic: str
    centres: dict[int, tuple[float, float]] = field(default_factory=dict)
    circle: Mapping[str, Any] | None = None
    T_base_laser: FloatArray | None = None

    @classmethod
    def named(cls, name: str, geometry: RunGeometry | None) -> ScannerView:
        """Scanner ``name``'s view (``default``: frame ``laser`` on ``/scan``, as a one-scanner run)."""
        frame = scanner_frame(name)
        topic = "/scan" if frame == FRAME_LASER else f"/scan/{name}"
        return cls(geometry, frame, topic, T_base_laser=geometry.nominal_base_laser if geometry else None)

    @property
    def suffix(self) -> str:
        """What tells this scanner's scene entities from another's (none for ``laser``)."""
        return self.frame[len(FRAME_LASER):]


def _import_foxglove() -> Any:
    try:
        import foxglove
    except ImportError:
        raise ConfigError(INSTALL_HINT) from None
    return foxglove


def _timestamp(fm: Any, time_s: float) -> Any:
    sec = int(time_s)
    return fm.Timestamp(sec, int((time_s - sec) * 1e9))


def _transform(fm: Any, stamp: Any, parent: str, child: str, matrix: FloatArray) -> Any:
    x, y, z, w = matrix_to_quat(matrix[:3, :3])
    return fm.FrameTransform(
        timestamp=stamp, parent_frame_id=parent, child_frame_id=child,
        translation=fm.Vector3(x=float(matrix[0, 3]), y=float(matrix[1, 3]), z=float(matrix[2, 3])),
        rotation=fm.Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)),
    )


def rod_frame(rod: RodLine) -> FloatArray:
    """tcp -> rod: the rod's origin, with z along its axis."""
    z = rod.unit_direction()
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return make_transform(np.column_stack([x, np.cross(z, x), z]), rod.origin_m)


def circle_points(circle: Mapping[str, Any]) -> list[tuple[float, float]]:
    """A closed polygon (u, v) around a fitted circle ``{"centre_uv_m", "radius_m"}``."""
    cu, cv = (float(c) for c in circle["centre_uv_m"])
    radius = float(circle["radius_m"])
    angles = np.linspace(0.0, 2 * math.pi, CIRCLE_SEGMENTS + 1)
    return [(cu + radius * math.cos(a), cv + radius * math.sin(a)) for a in angles]


class FoxgloveLiveView:
    """A Foxglove websocket server on loopback showing one run at a time.

    Call ``begin`` when a run starts, feed it every event (``view(event)`` or
    ``on_event(kind, data)``) from any one thread, and ``close`` it at the end.
    """

    def __init__(self, port: int = DEFAULT_PORT, name: str = "lasercal") -> None:
        fox = _import_foxglove()
        from foxglove import channels, messages

        self._fm = messages
        self._context = fox.Context()
        try:
            self._server = fox.start_server(name=name, host=LOOPBACK, port=port, context=self._context)
        except Exception as exc:  # the SDK raises its own error type for a busy port
            raise ConfigError(f"cannot serve the Foxglove live view on {LOOPBACK}:{port}: {exc}; "
                              "choose another --foxglove-port") from exc
        ctx = self._context
        self._scan_channels = {"/scan": channels.LaserScanChannel("/scan", context=ctx)}
        self._tf = channels.FrameTransformsChannel("/tf", context=ctx)
        self._scene = channels.SceneUpdateChannel("/lasercal/scene", context=ctx)
        self._log = channels.LogChannel("/lasercal/log", context=ctx)
        self._scanners: dict[str, ScannerView] = {}
        self._current = DEFAULT_SCANNER_NAME
        self.begin(None)

    @property
    def port(self) -> int:
        """The port the server listens on (useful when it was started on port 0)."""
        return int(self._server.port)

    @property
    def url(self) -> str:
        """The address the Foxglove app opens (``ws://127.0.0.1:PORT``)."""
        return f"ws://{LOOPBACK}:{self.port}"

    def begin(self, geometry: RunGeometry | None) -> None:
        """A new run of one scanner: forget the last one's centres and estimate."""
        self.begin_cell({DEFAULT_SCANNER_NAME: geometry})

    def begin_cell(self, geometries: Mapping[str, RunGeometry | None]) -> None:
        """A new run of a cell's scanners (by name, in the order they run), each in its own frame."""
        from foxglove import channels

        self._scanners = {name: ScannerView.named(name, geometry) for name, geometry in geometries.items()}
        self._current = next(iter(self._scanners))
        for view in self._scanners.values():
            if view.scan_topic not in self._scan_channels:
                self._scan_channels[view.scan_topic] = channels.LaserScanChannel(view.scan_topic,
                                                                               context=self._context)

    def __call__(self, event: EventLike) -> None:
        """Show one engine event (usable as ``on_event`` of ``calibrate``)."""
        self.on_event(event.kind, event.data, event.message)

    def on_event(self, kind: str, data: Mapping[str, Any], message: str = "") -> None:
        """Show one event given by kind and data (the daemon's stream carries these); a cell
        run's event is its scanner's (``data["scanner"]``)."""
        stamp = _timestamp(self._fm, time.time())
        if data.get("scanner") in self._scanners:
            self._current = str(data["scanner"])
        view = self._scanners[self._current]
        if kind == "scan":
            self._show_scan(stamp, view, data)
        elif kind == "centre":
            u, v = data["centre_uv_m"]
            view.centres[int(data["waypoint"])] = (float(u), float(v))
            _update_estimate(view)
            self._show_frames(stamp, data)
            self._show_scene(stamp)
        elif kind == "result":
            view.T_base_laser = np.asarray(data["T_base_laser"], dtype=float)
            self._show_frames(stamp, data)
        elif kind == "progress" and data.get("waypoint") is not None:
            self._show_frames(stamp, data)
        self._log.log(self._fm.Log(timestamp=stamp, level=self._fm.LogLevel.Info,
                                   message=message or f"{kind} {dict(data)}", name="lasercal"))

    def watch(self, request: RunRequest, on_event: Callable[[Any], None]) -> Callable[[Any], None]:
        """Start showing the run ``request`` asks for; the callback to give ``calibrate``:
        ``on_event`` and this view, both fed every event."""
        self.begin(RunGeometry.of_request(request))

        def both(event: Any) -> None:
            on_event(event)
            self(event)

        return both

    def watch_cell(self, request: CellRunRequest, on_event: Callable[[Any], None]) -> Callable[[Any], None]:
        """``watch`` for a cell job (``run.cell.calibrate_cell``): every scanner it runs in the scene."""
        job, names = cell_scanners(request)
        geometries = {}
        for name in names:
            scanner_job = job.for_scanner(name)
            geometries[name] = RunGeometry.of_job(scanner_job, planned_waypoints(scanner_job))
        self.begin_cell(geometries)

        def both(event: Any) -> None:
            on_event(event)
            self(event)

        return both

    def close(self) -> None:
        """Stop the server."""
        self._server.stop()

    def _show_scan(self, stamp: Any, view: ScannerView, data: Mapping[str, Any]) -> None:
        fm = self._fm
        ranges = [math.nan if r is None else float(r) for r in data["ranges_m"]]
        start = float(data["angle_min_rad"])
        end = start + float(data["angle_increment_rad"]) * max(len(ranges) - 1, 0)
        self._scan_channels[view.scan_topic].log(fm.LaserScan(
            timestamp=stamp, frame_id=view.frame, start_angle=start, end_angle=end, ranges=ranges))
        view.circle = data.get("circle")
        self._show_scene(stamp)

    def _show_scene(self, stamp: Any) -> None:
        """Every scanner's measured centres and latest fitted circle (if the rod was found) in
        its frame, and the rod."""
        fm = self._fm
        green = fm.Color(r=0.12, g=0.54, b=0.3, a=1.0)
        blue = fm.Color(r=0.17, g=0.42, b=0.69, a=1.0)
        entities = []
        deletions = []
        for view in self._scanners.values():
            entities.append(fm.SceneEntity(
                timestamp=stamp, frame_id=view.frame, id=f"measured_centres{view.suffix}", spheres=[
                    fm.SpherePrimitive(pose=fm.Pose(position=fm.Vector3(x=u, y=v, z=0.0),
                                                    orientation=fm.Quaternion(x=0, y=0, z=0, w=1)),
                                       size=fm.Vector3(x=0.01, y=0.01, z=0.01), color=green)
                    for u, v in view.centres.values()]))
            circle_id = f"fitted_circle{view.suffix}"
            if view.circle is not None:
                ring = [fm.Point3(x=u, y=v, z=0.0) for u, v in circle_points(view.circle)]
                entities.append(fm.SceneEntity(timestamp=stamp, frame_id=view.frame, id=circle_id, lines=[
                    fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, thickness=2.0,
                                     scale_invariant=True, points=ring, color=blue)]))
            else:  # the rod was not found in the scanner's latest scan
                deletions.append(fm.SceneEntityDeletion(
                    timestamp=stamp, type=fm.SceneEntityDeletionType.MatchingId, id=circle_id))
        geometry = self._scanners[self._current].geometry
        if geometry is not None:
            rod = geometry.rod
            cylinder = fm.CylinderPrimitive(
                pose=fm.Pose(position=fm.Vector3(x=0, y=0, z=rod.length_m / 2),
                             orientation=fm.Quaternion(x=0, y=0, z=0, w=1)),
                size=fm.Vector3(x=2 * rod.radius_m, y=2 * rod.radius_m, z=rod.length_m),
                color=fm.Color(r=0.87, g=0.42, b=0.13, a=0.9))
            entities.append(fm.SceneEntity(timestamp=stamp, frame_id=FRAME_ROD, id="rod", frame_locked=True,
                                           cylinders=[cylinder]))
        self._scene.log(fm.SceneUpdate(deletions=deletions, entities=entities))

    def _show_frames(self, stamp: Any, data: Mapping[str, Any]) -> None:
        """base -> tcp at the current scanner's waypoint, tcp -> rod, base -> every scanner's estimate."""
        fm = self._fm
        transforms = []
        geometry = self._scanners[self._current].geometry
        tcp_pose = data.get("tcp_pose")
        waypoint = data.get("waypoint")
        known = geometry is not None and waypoint is not None and 0 <= waypoint < len(geometry.tcp_poses)
        if tcp_pose is None and known:
            tcp_pose = geometry.tcp_poses[waypoint]
        if tcp_pose is not None:
            transforms.append(_transform(fm, stamp, FRAME_BASE, FRAME_TCP, pose_to_matrix(tcp_pose)))
        if geometry is not None:
            transforms.append(_transform(fm, stamp, FRAME_TCP, FRAME_ROD, rod_frame(geometry.rod)))
        transforms += [_transform(fm, stamp, FRAME_BASE, view.frame, view.T_base_laser)
                       for view in self._scanners.values() if view.T_base_laser is not None]
        if transforms:
            self._tf.log(fm.FrameTransforms(transforms=transforms))


def _update_estimate(view: ScannerView) -> None:
    """The closed-form fit of a scanner's centres so far, once there are enough of them."""
    geometry = view.geometry
    if geometry is None or len(view.centres) < MIN_CENTRES_FOR_ESTIMATE:
        return
    indices = [i for i in sorted(view.centres) if i < len(geometry.tcp_poses)]
    if len(indices) < MIN_CENTRES_FOR_ESTIMATE:
        return
    origins, directions = rod_lines_in_base(geometry.tcp_poses[indices], geometry.rod)
    centres = np.array([view.centres[i] for i in indices])
    initial = linear_initial_pose(origins, directions, centres, np.ones(len(indices)))
    view.T_base_laser = make_transform(initial.rotation, initial.translation)


@contextlib.contextmanager
def foxglove_view(port: int | None) -> Iterator[FoxgloveLiveView | None]:
    """The live view on ``127.0.0.1:port`` for the duration of the block (None: no view),
    as ``lasercal run --foxglove`` and ``lasercal serve --foxglove`` use it."""
    if port is None:
        yield None
        return
    view = FoxgloveLiveView(port=port)
    try:
        yield view
    finally:
        view.close()
