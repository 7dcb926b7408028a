"""A twist drill's flute phase estimated with the transform (docs/solver.md, "Flute phase").

The extraction cannot tell a twist drill's turn from one scan, so with ``rod.fluted`` it moves
each centre by the mean offset and widens its covariance over an unknown turn. The run knows
more: the bit turns with the tool, so its turn at every waypoint is one unknown phase plus what
the TCP poses and the helix give (``calibration/flutes.py``). This pass re-extracts the centres
as plain fits of the section, takes each one's offset at a trial phase out, solves, and keeps
the phase whose solution fits best (a profile over the half turn, refined by a parabola). The
phase's std comes from the profile: the larger of the best valley's width (chi-square up by one)
and the spread of every trial phase weighted by its likelihood (the profile has several valleys a
few in chi-square apart), scaled by the reduced chi-square when that is above 1; it is carried
into each centre's covariance with the model's own allowance.

The gate: the pass is kept only when its best phase fits the centres better than no flute
offsets at all by ``MIN_GAIN`` in chi-square (a round bit, or turns that leave the phase
unobservable, do not) and every solve of it succeeds; otherwise the widened solution stands,
as before.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from lasercal_hw.calibration.flutes import flute_offsets_m
from lasercal_hw.calibration.result import CalibrationResult
from lasercal_hw.calibration.solver import SolverOptions, solve
from lasercal_hw.errors import LasercalError
from lasercal_hw.models import FloatArray, Observation, RodLine
from lasercal_hw.scan.extraction import ExtractionSettings

#: Trial phases over the half turn (the section is point-symmetric).
PHASE_STEP_DEG = 4.0
#: What the section model leaves of a centre's offset, per axis, as a fraction of the radius
#: (drill job, seeds 100-101, range bias off: 1.5 mm RMS along the bearing, 1.8 mm across
#: with the fit's noise, ``benchmarks.flute_phase``; 0.15 r gave phases 30 deg off on seeds
#: 100-109, 0.25 r within 16 deg but one).
MODEL_ALLOWANCE_RADIUS_FRACTION = 0.25
#: The best phase must fit this much better in chi-square than no flutes at all (the centres
#: taken as they are, with the same allowance): 2 std for the one parameter.
MIN_GAIN = 4.0
#: How the pass re-extracts its plain centres: along the bearing as the ray fit puts them,
#: the frame its section model's offsets were measured in (``benchmarks.flute_phase``). With
#: the spot fit's centres the pass no longer helped: drill job, seeds 0-9, p95 4.52 mm /
#: 1.122 deg against 1.66 mm / 0.551 deg with these (docs/lab/solver-log.md, "Mended in
#: part"). Across it, too, as the ray fit puts them, not from the intensity's middle (a fluted
#: section's glint is no symmetric lobe: with it, drill job, 20 seeds, p95 1.168 -> 1.496 mm,
#: docs/lab/extraction-log.md, `intmid2`). Nor moved along by a polished rod's glint
#: (``glint_gloss_ratio``): the offsets are the ray fit's.
PLAIN_EXTRACTION = replace(
    ExtractionSettings(), fit_along_the_spot=False, echo_middle_levels=(), glint_gloss_ratio=0.0
)
#: A whitened residual's square counts at most this much in the profile (the solver's outlier
#: limit at 99.9 %), so that one bad centre does not pick the phase.
CAPPED_SQUARE = 13.8


@dataclass(frozen=True)
class FlutePhase:
    """The phase pass's solution and what it found."""

    result: CalibrationResult
    observations: list[Observation]
    phase_deg: float
    phase_std_deg: float
    #: The move of the plain centres that gave ``observations`` (the verify's re-fit repeats it).
    shift: FluteShift
    #: How much better in chi-square the phase fits than no flute offsets (the gate).
    gain: float
    note: str


def _cost(result: CalibrationResult) -> float:
    """The profile's measure of fit: every centre's whitened residual squared, capped."""
    return float(sum(min(r.whitened_norm**2, CAPPED_SQUARE) for r in result.residuals))


@dataclass(frozen=True)
class FluteShift:
    """The section's offset at every waypoint's turn taken out of plain fits: the offsets at
    ``phase_rad`` (times ``depth``: 0 for none) as ``T_base_laser`` and the bit's line ``rod``
    put each waypoint's crossing, each centre's covariance widened by the model's allowance and
    the phase's std. The pass and the verify's re-fit (``SecondPassRefit``) both move their
    centres through ``moved``."""

    T_base_laser: FloatArray
    rod: RodLine
    phase_rad: float
    phase_std_rad: float
    depth: float = 1.0

    def _offsets(
        self, tcp_poses: FloatArray, phase_rad: float, T_base_laser: FloatArray | None = None
    ) -> FloatArray:
        """The section's offset at each pose (N, 2), m, for the phase ``phase_rad``, as
        ``T_base_laser`` (None: the pass's) puts each crossing."""
        settings = ExtractionSettings()
        return flute_offsets_m(
            phase_rad,
            self.T_base_laser if T_base_laser is None else T_base_laser,
            tcp_poses,
            self.rod,
            web_fraction=settings.flute_web_fraction,
            opening_deg=settings.flute_opening_deg,
        )

    def offsets_m(self, tcp_poses: FloatArray, T_base_laser: FloatArray | None = None) -> FloatArray:
        """The offsets ``moved`` takes out (N, 2), m, with the crossings where ``T_base_laser``
        (None: the pass's) puts them: the verify's model of a moved scanner asks for those of
        a moved transform."""
        return self.depth * self._offsets(np.asarray(tcp_poses, dtype=float), self.phase_rad, T_base_laser)

    def allowance_uv_m2(self) -> FloatArray:
        """What the section model leaves of a centre's offset (2, 2), m^2: ``moved`` widens every
        centre's covariance by it."""
        return np.eye(2) * (MODEL_ALLOWANCE_RADIUS_FRACTION * self.rod.radius_m) ** 2

    def moved(
        self,
        tcp_poses: FloatArray,
        centres_uv_m: Sequence[FloatArray],
        covariances_uv_m2: Sequence[FloatArray],
    ) -> list[tuple[FloatArray, FloatArray]]:
        """Each plain centre (m) with the offset taken out, and its covariance (m^2) widened."""
        poses = np.asarray(tcp_poses, dtype=float)
        offset = self.offsets_m(poses)
        spread = 0.5 * self.depth * (
            self._offsets(poses, self.phase_rad + self.phase_std_rad)
            - self._offsets(poses, self.phase_rad - self.phase_std_rad)
        )
        allowance = self.allowance_uv_m2()
        return [
            (
                np.asarray(centre, dtype=float) - shift,
                np.asarray(covariance, dtype=float) + allowance + np.outer(dphase, dphase),
            )
            for centre, covariance, shift, dphase in zip(
                centres_uv_m, covariances_uv_m2, offset, spread, strict=True
            )
        ]

    def observations(self, plain: Sequence[Observation]) -> list[Observation]:
        """The plain centres moved (``moved``)."""
        moved = self.moved(
            np.array([o.tcp_pose for o in plain], dtype=float),
            [o.centre_uv_m for o in plain],
            [o.covariance_uv_m2 for o in plain],
        )
        return [
            replace(o, centre_uv_m=centre, covariance_uv_m2=covariance)
            for o, (centre, covariance) in zip(plain, moved, strict=True)
        ]


def _shifted(
    plain: Sequence[Observation],
    result: CalibrationResult,
    rod: RodLine,
    phase_rad: float,
    phase_std_rad: float,
    depth: float = 1.0,
) -> list[Observation]:
    """The plain centres moved by the section's offset at ``phase_rad`` as ``result`` puts the
    bit (``FluteShift``)."""
    shift = FluteShift(result.matrix(), result.estimated_rod(rod), phase_rad, phase_std_rad, depth)
    return shift.observations(plain)


def parabola_minimum(phases_rad: FloatArray, costs: FloatArray, best: int) -> tuple[float, float]:
    """The profile's minimum by a parabola through the best trial and its neighbours (the grid
    wraps at the half turn), and the half-width at which it rises by one (rad)."""
    step = phases_rad[1] - phases_rad[0]
    left, mid, right = costs[best - 1], costs[best], costs[(best + 1) % len(costs)]
    curvature = (left - 2.0 * mid + right) / step**2
    if curvature <= 0.0:
        return float(phases_rad[best]), float(step)
    shift = float(np.clip(0.5 * (left - right) / (curvature * step), -0.5, 0.5)) * step
    return float(phases_rad[best] + shift), float(np.sqrt(2.0 / curvature))


def profile_spread_rad(phases_rad: FloatArray, costs: FloatArray, phase_rad: float) -> float:
    """The phase's std over the whole half turn: every trial weighted by its likelihood
    ``exp(-(cost - best) / 2)``, its distance to ``phase_rad`` taken the short way round the
    half turn. The section's offsets jump where a flute's edge meets a land, so the profile has
    several valleys a few in chi-square apart; the parabola sees only the best one's width."""
    finite = np.isfinite(costs)
    weights = np.exp(-0.5 * (costs[finite] - costs[finite].min()))
    distance = (phases_rad[finite] - phase_rad + np.pi / 2.0) % np.pi - np.pi / 2.0
    return float(np.sqrt(np.sum(weights * distance**2) / np.sum(weights)))


def estimate_flute_phase(
    plain: Sequence[Observation],
    widened: CalibrationResult,
    rod: RodLine,
    options: SolverOptions,
) -> FlutePhase | None:
    """The phase pass over ``plain`` centres (plain fits, the range offset out) from the
    widened solution ``widened`` of ``rod``; None when the gate (module docstring) refuses it."""
    phases = np.radians(np.arange(0.0, 180.0, PHASE_STEP_DEG))
    costs = np.full(len(phases), np.inf)
    for k, phase in enumerate(phases):
        try:
            costs[k] = _cost(solve(_shifted(plain, widened, rod, phase, 0.0), rod, options=options))
        except LasercalError:
            continue
    if not np.isfinite(costs).any():
        return None
    best = int(np.argmin(costs))
    phase, std = parabola_minimum(phases, costs, best)
    std = max(std, profile_spread_rad(phases, costs, phase))
    try:
        trial = solve(_shifted(plain, widened, rod, phase, 0.0), rod, options=options)
        std *= np.sqrt(max(1.0, trial.reduced_chi_square))
        shift = FluteShift(trial.matrix(), trial.estimated_rod(rod), phase, std)
        observations = shift.observations(plain)
        result = solve(observations, rod, options=options)
        flat = _cost(solve(_shifted(plain, widened, rod, 0.0, 0.0, depth=0.0), rod, options=options))
    except LasercalError:
        return None
    phase_deg, std_deg = float(np.degrees(phase)) % 180.0, float(np.degrees(std))
    gain = flat - _cost(trial)
    if gain < MIN_GAIN:
        return None
    note = (
        f"flute phase {phase_deg:.0f} +- {std_deg:.0f} deg from the tool's x axis (the bit's section "
        f"modelled at every waypoint's turn; chi-square {gain:.0f} below no flutes)"
    )
    return FlutePhase(result, observations, phase_deg, std_deg, shift, gain, note)
