"""A twist drill's flute phase told by a short spin before the waypoints, and the waypoints'
tool turned to it (``trajectory.flute_phase_deg``; docs/solver.md, "Flute phase").

Where a fluted bit's centre lies depends on how it faces the scanner: the tool's turn about the
bit, the bit's unknown turn in its chuck (the flute phase) and the helix. A waypoint file is
checked at one phase; a bit clamped at another brings many crossings to a flute's edge, where
the section model (``calibration/flutes.py``) is off by 2-2.5 mm. So the run first dwells at
the first waypoint turned about the bit's nominal axis to ``SPIN_TURNS_DEG`` (the crossing stays
where it is), fits the centres' pattern against the turn (the flute offset at a trial phase,
180 deg periodic, plus the crossing and the bit's offset from its nominal axis, which turns with
the tool), and turns every waypoint's tool about the bit by ``flute_phase_deg - phase``
(modulo the half turn), which gives back the facings the file was checked at.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from lasercal_hw.calibration.flutes import flute_offsets_m
from lasercal_hw.config import JobConfig
from lasercal_hw.geometry import matrix_to_pose, pose_to_matrix, rotvec_to_matrix
from lasercal_hw.models import FloatArray, RodLine
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.run.devices import Robot, Scanner
from lasercal_hw.run.flute_phase import (
    CAPPED_SQUARE,
    MIN_GAIN,
    MODEL_ALLOWANCE_RADIUS_FRACTION,
    PLAIN_EXTRACTION,
    parabola_minimum,
    profile_spread_rad,
)
from lasercal_hw.run.outcome import solve_run
from lasercal_hw.run.preflight import is_clear
from lasercal_hw.run.records import (
    Measured,
    Progress,
    ProgressCallback,
    ResumeState,
    RunOutcome,
    RunRecorder,
    WaypointMeasurement,
)
from lasercal_hw.run.resume import DESIGN_EVENT
from lasercal_hw.run.sequencer import Sequencer
from lasercal_hw.run.two_pass import predict_rod
from lasercal_hw.run.waypoints import listed_waypoints
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction import RodNotFoundError, find_rod_centre

#: The spin's tool turns about the bit, from the first waypoint's (deg), in the order visited: a
#: whole turn (from the waypoint's own turn, so that the background is taken above the waypoint
#: as for any job), so that the bit's offset from its nominal axis (once a turn) stands apart from the
#: flutes' pattern (twice a turn), and its two halves 15 deg apart, so that the facings of the half
#: turn come every 15 deg. Seeds 100-119 of ``drill-fluted-any-turn``: the phase within 4.1 deg
#: (median; 95th percentile 15) against 6.4 (14.8) for nine turns -80..80 by 20, which left one
#: spin of twenty not told.
SPIN_TURNS_DEG = tuple(float(t) for t in (*range(0, 180, 30), *range(195, 360, 30)))
#: Trial phases over the half turn (deg).
PHASE_STEP_DEG = 2.0
#: Where a waypoint turned to the phase is out of reach (the turn about the bit brings the wrist
#: where the arm cannot go: the 12th of examples/drill-waypoints.csv from a turn of +80 deg on a
#: UR5), the steps (deg) by which the turns tried instead come back to the waypoint's turn as listed.
REACH_STEP_DEG = 10.0


@dataclass(frozen=True)
class SpinPhase:
    """The flute phase the spin tells and the tool turn that brings the waypoints to the
    phase they were checked at."""

    phase_deg: float
    phase_std_deg: float
    #: How much better in chi-square the phase fits the spin than no flute offsets.
    gain: float
    shift_deg: float
    centres: int

    @property
    def note(self) -> str:
        """The run's one line on it."""
        return (
            f"flute phase ~{self.phase_deg:.0f} +- {self.phase_std_deg:.0f} deg from the spin "
            f"({self.centres} centres, chi-square {self.gain:.0f} below no flutes): tool turns shifted "
            f"by {self.shift_deg:+.0f} deg"
        )


def turned_about_bit(poses: FloatArray, rod: RodLine, turn_deg: float | FloatArray) -> FloatArray:
    """``poses`` (UR vectors, N x 6) with the tool turned by ``turn_deg`` (one, or one per pose)
    about the bit's nominal axis, which stays where it was."""
    matrices = pose_to_matrix(np.atleast_2d(np.asarray(poses, dtype=float)))
    direction = rod.unit_direction()
    origin = np.asarray(rod.origin_m, dtype=float)
    turns = np.broadcast_to(np.radians(np.asarray(turn_deg, dtype=float)), (len(matrices),))
    turned = np.empty_like(matrices)
    for k, (matrix, turn) in enumerate(zip(matrices, turns, strict=True)):
        about = np.eye(4)
        about[:3, :3] = rotvec_to_matrix(direction * turn)
        about[:3, 3] = origin - about[:3, :3] @ origin
        turned[k] = matrix @ about
    return matrix_to_pose(turned)


def spin_poses(first_waypoint: FloatArray, rod: RodLine) -> FloatArray:
    """The spin: the first waypoint with the tool turned to each of ``SPIN_TURNS_DEG``."""
    turns = np.array(SPIN_TURNS_DEG)
    return turned_about_bit(np.repeat(np.atleast_2d(first_waypoint), len(turns), axis=0), rod, turns)


def tool_shift_deg(phase_deg: float, checked_phase_deg: float) -> float:
    """The tool turn that brings a bit at ``phase_deg`` to ``checked_phase_deg``, the shortest
    way round the half turn (-90 to 90 deg)."""
    return float((checked_phase_deg - phase_deg + 90.0) % 180.0 - 90.0)


def turns_to_try_deg(shift_deg: float) -> list[float]:
    """The tool turns (deg) tried at a waypoint, nearest the checked facing first: ``shift_deg``,
    the same facing the other way round (a two-fluted section repeats every half turn), then
    even steps of at most ``REACH_STEP_DEG`` back to the turn as listed (0)."""
    other_way_deg = shift_deg - float(np.copysign(180.0, shift_deg))
    steps = int(np.ceil(abs(shift_deg) / REACH_STEP_DEG))
    return [shift_deg, other_way_deg, *(shift_deg * (1.0 - j / steps) for j in range(1, steps + 1))]


def turned_within_reach(
    listed: FloatArray, rod: RodLine, shift_deg: float, reachable: Callable[[FloatArray], bool]
) -> tuple[FloatArray, dict[int, float | None]]:
    """``listed`` (UR poses, N x 6) with the tool turned about the bit by ``shift_deg``, each
    waypoint whose turned pose is not ``reachable`` by the first of ``turns_to_try_deg`` that is;
    and the turn (deg) taken at each of those, None where none is (kept as listed: the preflight
    names it)."""
    turned = turned_about_bit(listed, rod, shift_deg)
    instead: dict[int, float | None] = {}
    for k, pose in enumerate(np.asarray(listed, dtype=float)):
        if reachable(turned[k]):
            continue
        instead[k] = None
        turned[k] = pose
        for turn_deg in turns_to_try_deg(shift_deg)[1:]:
            candidate = turned_about_bit(pose, rod, turn_deg)[0]
            if reachable(candidate):
                instead[k], turned[k] = turn_deg, candidate
                break
    return turned, instead


def _square_to_bit(rod: RodLine) -> FloatArray:
    """Two unit directions square to the bit's nominal axis, in the tool frame (3, 2)."""
    direction = rod.unit_direction()
    first = np.cross(direction, [1.0, 0.0, 0.0] if abs(direction[0]) < 0.9 else [0.0, 1.0, 0.0])
    first /= np.linalg.norm(first)
    return np.column_stack([first, np.cross(direction, first)])


def _offset_basis(T_base_laser: FloatArray, poses: FloatArray, rod: RodLine) -> FloatArray:
    """How the bit's offset from its nominal axis (along ``_square_to_bit``, tool frame) moves
    each spin centre in the scan plane (N, 2, 2)."""
    direction = rod.unit_direction()
    square = _square_to_bit(rod)
    to_scanner = np.asarray(T_base_laser, dtype=float)[:3, :3].T
    basis = np.empty((len(poses), 2, 2))
    for k, pose in enumerate(poses):
        rotation = to_scanner @ pose_to_matrix(pose)[:3, :3]
        axis, moved = rotation @ direction, rotation @ square
        basis[k] = (moved - np.outer(axis, moved[2] / axis[2]))[:2]
    return basis


def plain_spin_centres(
    measurements: Sequence[WaypointMeasurement], T_base_laser: FloatArray, rod: RodLine,
    background: AveragedScan | None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The spin's centres extracted again as plain fits along the nominal axis (the frame the
    section model was measured in): poses (N, 6), centres (N, 2) and covariances (N, 2, 2)."""
    poses, centres, covariances = [], [], []
    for m in measurements:
        predicted = predict_rod(T_base_laser, m.tcp_pose, rod)
        try:
            centre = find_rod_centre(
                m.averaged, radius_m=rod.radius_m, background=background,
                axis_in_scanner=predicted.axis_in_scanner, expected_uv_m=predicted.expected_uv_m,
                settings=PLAIN_EXTRACTION,
            )
        except RodNotFoundError:
            continue
        poses.append(m.tcp_pose)
        centres.append(centre.centre_uv_m)
        covariances.append(centre.covariance_uv_m2)
    return (
        np.array(poses).reshape(-1, 6),
        np.array(centres).reshape(-1, 2),
        np.array(covariances).reshape(-1, 2, 2),
    )


def _fit(centres: FloatArray, weights: FloatArray, design: FloatArray) -> tuple[float, FloatArray]:
    """The capped chi-square of the best crossing and axis offset for ``centres`` (N, 2), and
    that solution (crossing, offset; m)."""
    normal = np.einsum("nji,njk,nkl->il", design, weights, design)
    rhs = np.einsum("nji,njk,nk->i", design, weights, centres)
    solution = np.linalg.lstsq(normal, rhs, rcond=None)[0]
    residual = centres - design @ solution
    squares = np.einsum("ni,nij,nj->n", residual, weights, residual)
    return float(np.sum(np.minimum(squares, CAPPED_SQUARE))), solution


def phase_from_spin(
    poses: FloatArray, centres: FloatArray, covariances: FloatArray, T_base_laser: FloatArray,
    rod: RodLine, checked_phase_deg: float,
) -> SpinPhase | None:
    """The flute phase whose section offsets best explain the spin's centres, or None when it
    fits no better than no flutes by ``MIN_GAIN`` in chi-square (or too few centres)."""
    if len(centres) < 5:
        return None
    allowance = np.eye(2) * (MODEL_ALLOWANCE_RADIUS_FRACTION * rod.radius_m) ** 2
    weights = np.linalg.inv(covariances + allowance)
    crossing = np.broadcast_to(np.eye(2), (len(poses), 2, 2))
    design = np.concatenate([crossing, _offset_basis(T_base_laser, poses, rod)], axis=2)
    square = _square_to_bit(rod)

    def cost(phase_rad: float) -> float:
        """The fit at a trial phase, its offsets taken again on the bit where the first fit puts
        it: 2 mm off the nominal axis, the crossings lie a few degrees further along the helix."""
        _, solution = _fit(centres - flute_offsets_m(phase_rad, T_base_laser, poses, rod), weights, design)
        bit = replace(rod, origin_m=np.asarray(rod.origin_m, dtype=float) + square @ solution[2:])
        return _fit(centres - flute_offsets_m(phase_rad, T_base_laser, poses, bit), weights, design)[0]

    phases = np.radians(np.arange(0.0, 180.0, PHASE_STEP_DEG))
    costs = np.array([cost(p) for p in phases])
    flat = _fit(centres, weights, design)[0]
    best = int(np.argmin(costs))
    gain = flat - costs[best]
    if gain < MIN_GAIN:
        return None
    phase, width = parabola_minimum(phases, costs, best)
    std = max(width, profile_spread_rad(phases, costs, phase))
    phase_deg, std_deg = float(np.degrees(phase)) % 180.0, float(np.degrees(std))
    shift_deg = tool_shift_deg(phase_deg, checked_phase_deg)
    return SpinPhase(phase_deg, std_deg, float(gain), shift_deg, len(centres))


def job_spin(job: JobConfig) -> FloatArray:
    """A ``flute_phase_deg`` job's first part: the spin at its first waypoint."""
    return spin_poses(listed_waypoints(job)[0], job.rod.rod_line())


@dataclass(frozen=True)
class TurnedWaypoints:
    """The rest of a spun run: the job's waypoints turned to the bit's phase (or as listed when
    the spin did not tell it), and the run's note on it."""

    phase: SpinPhase | None
    waypoints: FloatArray
    note: str
    #: Listed indices kept as listed because no turn of them is within reach (the preflight names them).
    out_of_reach: tuple[int, ...] = ()


def turn_waypoints(
    job: JobConfig,
    spin: Sequence[WaypointMeasurement],
    background: AveragedScan | None,
    reachable: Callable[[FloatArray], bool],
) -> TurnedWaypoints:
    """The job's waypoints turned by what the spin's measurements tell of the flute phase, each
    within reach (``turned_within_reach``; ``reachable``: a pose passes the preflight's checks)."""
    assert job.scanner.nominal is not None and job.trajectory.flute_phase_deg is not None
    rod, T_nominal = job.rod.rod_line(), job.scanner.nominal.matrix()
    poses, centres, covariances = plain_spin_centres(spin, T_nominal, rod, background)
    phase = phase_from_spin(poses, centres, covariances, T_nominal, rod, job.trajectory.flute_phase_deg)
    listed = listed_waypoints(job)
    if phase is None:
        note = (
            f"the flute phase was not told by the spin ({len(centres)} of {len(SPIN_TURNS_DEG)} centres "
            "found): the waypoints keep their tool turns"
        )
        return TurnedWaypoints(None, listed, note)
    turned, instead = turned_within_reach(listed, rod, phase.shift_deg, reachable)
    if not instead:
        return TurnedWaypoints(phase, turned, phase.note)
    first = len(SPIN_TURNS_DEG)
    taken = ", ".join(
        f"waypoint {first + k} (listed {k}) "
        + ("kept as listed, no turn within reach" if turn is None else f"by {turn + 0.0:+.0f} deg")
        for k, turn in instead.items()
    )
    note = f"{phase.note}; out of reach so, turned otherwise: {taken}"
    return TurnedWaypoints(phase, turned, note, tuple(k for k, turn in instead.items() if turn is None))


def run_turned_waypoints(
    robot: Robot,
    scanner: Scanner,
    recorder: RunRecorder,
    job: JobConfig,
    waypoints: FloatArray,
    spun: Measured,
    *,
    on_progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
    clock: Callable[[], float] = time.time,
    resumed_turn_note: str | None = None,
) -> RunOutcome:
    """After the spin (``waypoints``, as measured in ``spun``): tell the phase, record the turned
    waypoints (a ``trajectory_design`` event that ``--resume`` reads, with the phase and the
    shift), measure them and solve over every centre. A run resumed after the turn already
    holds every waypoint and is solved as it is, its note on the turn (``resumed_turn_note``,
    as recorded) leading the refinement as a run's own does."""
    spin_count = len(SPIN_TURNS_DEG)
    if len(waypoints) > spin_count:
        outcome = solve_run(spun, job, recorder, on_progress=on_progress, cancel=cancel, clock=clock)
        if resumed_turn_note is None:
            return outcome
        return dataclasses.replace(outcome, refinement=f"{resumed_turn_note}; {outcome.refinement}")
    rod = job.rod.rod_line()
    turned = turn_waypoints(
        job, spun.measurements, spun.background, lambda pose: is_clear(robot, pose, rod, job.workspace)
    )
    phase = turned.phase
    recorder.write_event(
        clock(), DESIGN_EVENT,
        phase=2,
        first_index=spin_count,
        waypoints=turned.waypoints.tolist(),
        flute_phase_deg=None if phase is None else phase.phase_deg,
        flute_phase_std_deg=None if phase is None else phase.phase_std_deg,
        tool_turn_shift_deg=0.0 if phase is None else phase.shift_deg,
        notes=[turned.note],
    )
    every_waypoint = np.vstack([waypoints, turned.waypoints])
    if on_progress is not None:
        done = len(spun.measurements) + len(spun.skipped)
        on_progress(Progress("move", turned.note, waypoint_count=len(every_waypoint), completed=done,
                             time_left_s=0.0))
    sequencer = Sequencer(
        robot, scanner, recorder, job, every_waypoint,
        on_progress=on_progress,
        resume=ResumeState(spun.measurements, spun.skipped, spun.background),
        cancel=cancel,
        clock=clock,
    )
    outcome = solve_run(sequencer.measure(), job, recorder,
                        on_progress=on_progress, cancel=cancel, clock=clock)
    outcome.timings.motion_s += spun.timings.motion_s
    outcome.timings.dwell_s += spun.timings.dwell_s
    outcome.timings.wall_s += spun.timings.wall_s
    return dataclasses.replace(outcome, refinement=f"{turned.note}; {outcome.refinement}")
