"""What a calibration run produces and reports, as plain records: the progress steps, the
waypoints measured or skipped, the timings, the state a resumed run starts from and the
outcome; and the recorder interface the run writes every event to.

Records only: the motion (``run/sequencer``) and the solve (``run/two_pass``) both use them,
and the offline replay and verify import them without any motion code.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from lasercal_hw.calibration.observations import SolveSettings
from lasercal_hw.calibration.quality import Verdict
from lasercal_hw.calibration.result import CalibrationResult
from lasercal_hw.models import FloatArray, LaserScan, Observation
from lasercal_hw.run.preflight import PreflightReport
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction import RodCentre

if TYPE_CHECKING:
    from lasercal_hw.run.two_pass import SecondPassRefit


class RunRecorder(Protocol):
    """The part of ``SessionRecorder`` the sequencer writes to."""

    def write_scan(self, scan: LaserScan, scanner: str | None = None) -> None: ...

    def write_tcp_pose(self, host_time_s: float, pose: FloatArray) -> None: ...

    def write_joint_state(self, host_time_s: float, q_rad: FloatArray) -> None: ...

    def write_event(self, host_time_s: float, kind: str, **fields: Any) -> None: ...


@dataclass(frozen=True)
class Progress:
    """One step of the run, for a live display. ``waypoint`` indexes the waypoint list."""

    stage: str
    message: str
    waypoint: int | None = None
    waypoint_count: int = 0
    completed: int = 0
    scans_averaged: int | None = None
    centre_uv_m: tuple[float, float] | None = None
    #: Where the nominal mounting said the rod would be (None without ``scanner.nominal``).
    expected_uv_m: tuple[float, float] | None = None
    time_left_s: float | None = None
    reason: str | None = None
    averaged: AveragedScan | None = field(default=None, repr=False)
    centre: RodCentre | None = field(default=None, repr=False)


ProgressCallback = Callable[[Progress], None]


@dataclass(frozen=True)
class WaypointMeasurement:
    """A waypoint where the rod was found: the TCP pose, the averaged scan and the centre."""

    index: int
    tcp_pose: FloatArray
    averaged: AveragedScan
    centre: RodCentre

    def observation(self) -> Observation:
        """The solver's view of this waypoint."""
        return Observation(
            index=self.index,
            tcp_pose=np.asarray(self.tcp_pose, dtype=float),
            centre_uv_m=np.asarray(self.centre.centre_uv_m, dtype=float),
            covariance_uv_m2=np.asarray(self.centre.covariance_uv_m2, dtype=float),
            noise_covariance_uv_m2=np.asarray(self.centre.dwell_noise_covariance_uv_m2(), dtype=float),
        )


@dataclass(frozen=True)
class SkippedWaypoint:
    """A waypoint that gave no observation, and why."""

    index: int
    reason: str


@dataclass
class Timings:
    """Where the run's time went (seconds)."""

    wall_s: float = 0.0
    motion_s: float = 0.0
    dwell_s: float = 0.0

    @property
    def overhead_s(self) -> float:
        """Time spent neither moving nor dwelling (checks, averaging, fitting, solving)."""
        return self.wall_s - self.motion_s - self.dwell_s

    @property
    def overhead_fraction(self) -> float:
        """Overhead relative to the motion and dwell time (the target is under 0.10)."""
        busy_s = self.motion_s + self.dwell_s
        return self.overhead_s / busy_s if busy_s > 0 else 0.0


@dataclass(frozen=True)
class ResumeState:
    """What an interrupted run already measured (see ``lasercal_hw.run.resume``)."""

    measurements: list[WaypointMeasurement] = field(default_factory=list)
    skipped: list[SkippedWaypoint] = field(default_factory=list)
    background: AveragedScan | None = None
    #: What a spun run said of its flute phase and its waypoints' turn, where it got that far.
    turn_note: str | None = None

    @property
    def finished_indices(self) -> set[int]:
        """Waypoints that need no further visit."""
        return {m.index for m in self.measurements} | {s.index for s in self.skipped}


@dataclass(frozen=True)
class RunOutcome:
    """Everything a finished run produced."""

    preflight: PreflightReport
    measurements: list[WaypointMeasurement]
    skipped: list[SkippedWaypoint]
    observations: list[Observation]
    first_pass: CalibrationResult
    result: CalibrationResult
    refinement: str
    verdict: Verdict
    timings: Timings
    resumed_from: int
    background: AveragedScan | None
    #: How ``observations`` solve to ``result`` (the rod, solver settings and gates).
    solve_settings: SolveSettings
    #: (waypoint, warning) for each solved centre that may be off by more than its covariance.
    centre_warnings: list[tuple[int, str]]
    #: How the solved centres were fitted (``TwoPassSolution.refit``; ``result.json`` records it).
    refit: SecondPassRefit
    #: The UR pose of every waypoint the run planned (N, 6), by index: an adaptive run's second
    #: design and a spun run's turned waypoints included (``result.json``'s ``run.waypoints``).
    waypoints: FloatArray


@dataclass(frozen=True)
class Measured:
    """What ``Sequencer.measure`` gathered (no solve)."""

    preflight: PreflightReport
    measurements: list[WaypointMeasurement]
    skipped: list[SkippedWaypoint]
    background: AveragedScan | None
    timings: Timings
    #: The UR pose of every waypoint the sequencer was given (N, 6), by index.
    waypoints: FloatArray
    #: Waypoints a resumed run had already measured or skipped before this call.
    resumed_from: int = 0


def record_event(recorder: RunRecorder, host_time_s: float, kind: str, **fields: Any) -> None:
    """Write one event with its fields made JSON-able (arrays, dataclasses, models)."""
    recorder.write_event(host_time_s, kind, **_jsonable(fields))


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if hasattr(value, "model_dump"):
        return _jsonable(value.model_dump(mode="json"))
    if hasattr(value, "__dataclass_fields__"):
        return {name: _jsonable(getattr(value, name)) for name in value.__dataclass_fields__}
    return value
