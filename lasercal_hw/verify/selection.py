"""Which of the job's waypoints a verify visits.

The subset of ``count`` waypoints maximises ``log det(F_S + P^-1)`` (Bayesian D-optimal
design): ``F_S`` is the Fisher information of the correction ``(dt, e)`` from the chosen
waypoints under the drift test's own noise model (``drift.noise_blocks``), with each
waypoint's centre covariance as the calibration's solver weighed it there and the part of it
a dwell draws anew (both recorded in ``result.json``; a waypoint it has none for:
``DESIGN_SIGMA_UV_M``, all of it drawn anew). At a waypoint the calibration measured, the test
takes only what a dwell draws anew (the rest repeats and cancels), and so does the choice: a
centre whose covariance is mostly the rod's shape or a pull that repeats at the pose is as good
a test as its noise says. A warned centre (a rod blended with the wall behind it, tens of mm of
std, all of it drawn anew) counts for the little it tells, where one assumed noise for all made
it a waypoint of every verify. ``P`` is the correction's prior (``drift``). A
large determinant means a small confidence ellipsoid in every direction at once, so the
chosen waypoints spread over the scan plane and the tool tilts by themselves: a subset
that left one direction of the transform untested would have a near-zero factor there.
Greedy selection, then exchanges until no swap improves the determinant; with a time
budget (``verify.max_time_fraction`` of the calibration's own motion and dwell, estimated
by ``run.timing``), the exchanges keep the subset inside it.

The verify passes the verdict's tolerances (``VerdictAim``), and then the exchanges first raise
what the verdict weighs (``tolerance_noncentrality``: how well the test sees a move of the
tolerance in its weakest direction) up to a little past what the test needs, and only then the
determinant: a large determinant can hide one direction seen poorly (on the default job a turn
about an axis near base y), and the verdict says ``ok`` only where that direction too is seen
at the tolerance; past that, the determinant keeps the move's estimate good. Where no subset
found reaches what the test needs, the verdict cannot vouch anyway and the choice is the D-optimal
one: raising the weakest direction alone can leave a shift as weak as the turn it cannot see
(docs/lab/verify-log.md, "The choice weighs what the verdict weighs").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.calibration.model import plane_crossing, rod_lines_in_base, whitening
from lasercal_hw.errors import CalibrationError
from lasercal_hw.models import FloatArray
from lasercal_hw.verify.drift import DriftModel, needed_noncentrality, noise_blocks, predictions

#: How far past the non-centrality the test needs (``drift.needed_noncentrality``) the choice aims
#: a move of the verdict's tolerance in its weakest direction, since the calibration's record only
#: estimates the verify dwell's noise; past that aim the determinant decides.
VERDICT_MARGIN = 1.2
#: Centre noise the design assumes where the calibration recorded none (a 20 mm rod over a
#: 3 s dwell: about 0.5 mm per axis).
DESIGN_SIGMA_UV_M = 0.0005
MIN_INCIDENCE_DEG = 10.0
MIN_WAYPOINTS = 2


@dataclass(frozen=True)
class VerdictAim:
    """The verdict's tolerances the choice weighs (shift, m; turn, rad) and how far past the
    test's needed non-centrality it aims (``VERDICT_MARGIN``)."""

    shift_m: float
    turn_rad: float
    margin: float = VERDICT_MARGIN


@dataclass(frozen=True)
class Selection:
    """The chosen waypoints (indices into the job's list, in visiting order) and the std
    of the correction they are expected to give (mm, deg; about base x, y, z)."""

    indices: list[int]
    candidates: int
    expected_std_shift_mm: list[float]
    expected_std_turn_deg: list[float]
    estimated_time_s: float | None = None
    #: Which centre noise the choice weighed the candidates with (``centre_noise_note``).
    centre_noise: str = ""
    #: Waypoints through the plane that were no candidates: the calibration visited them without
    #: a centre it used (no rod found, or an outlier), or visited their pose before.
    left_out: list[int] = field(default_factory=list)
    #: How the subset was chosen (``aim_note``): for the verdict's aim, or D-optimal and why.
    choice: str = ""
    #: Whether the subset sees a move of the verdict's tolerance as the test needs, by the noise
    #: the choice weighed (False: an unmoved verify is likely ``inconclusive``; None: not weighed).
    vouches: bool | None = None


def _crosses_plane(model: DriftModel, waypoints: FloatArray) -> np.ndarray:
    """Waypoints whose rod, by the active calibration, pierces the scan plane steeply
    enough, between its ends and inside the scanner's field of view (+-135 deg)."""
    T = np.asarray(model.T_base_laser, dtype=float)
    origins, directions = rod_lines_in_base(waypoints, model.rod)
    crossing, _, line_s = plane_crossing(T[:3, :3], T[:3, 3], origins, directions)
    incidence_deg = np.degrees(np.arcsin(np.clip(np.abs(directions @ T[:3, 2]), 0.0, 1.0)))
    bearing_deg = np.degrees(np.arctan2(crossing[:, 1], crossing[:, 0]))
    return (
        (incidence_deg >= MIN_INCIDENCE_DEG)
        & (line_s >= 0.0)
        & (line_s <= model.rod.length_m)
        & (np.abs(bearing_deg) <= 135.0)
    )


def waypoint_information(
    model: DriftModel,
    waypoints: FloatArray,
    visited: NDArray[np.bool_],
    centre_covariance_uv_m2: FloatArray,
    noise_covariance_uv_m2: FloatArray | None = None,
) -> FloatArray:
    """Fisher information (N, 6, 6) of the correction from each waypoint alone, its centre
    covariance (N, 2, 2) and the part of it a dwell draws anew (N, 2, 2; None: all of it) taken
    as the drift test takes them (``drift.noise_blocks``); the calibration's covariance, which
    correlates the waypoints it did not visit, left out."""
    _, jac, slope = predictions(model, waypoints)
    centre = np.asarray(centre_covariance_uv_m2, dtype=float)
    white = whitening(noise_blocks(model, slope, centre, visited, noise_covariance_uv_m2))
    whitened = white @ jac
    return np.swapaxes(whitened, 1, 2) @ whitened


def centre_noise_note(known: NDArray[np.bool_], noise_known: NDArray[np.bool_] | None = None) -> str:
    """Which centre noise the choice weighed ``known.size`` candidates with (``known``: the
    calibration recorded the centre covariance there; ``noise_known``: and the part of it a
    dwell draws anew, None: nowhere), for ``verify.json``'s selection."""
    assumed = f"{DESIGN_SIGMA_UV_M * 1e3:g} mm per axis assumed"
    drawn = int(0 if noise_known is None else (noise_known & known).sum())
    if known.all():
        part = f" (of it only what a dwell draws anew, at {drawn} of them)" if drawn else ""
        return f"the centre covariance the calibration's solver weighed each candidate with{part}"
    if not known.any():
        return (
            f"{assumed} at every candidate: the calibration's result.json records no centre covariance "
            "(written before it did, or it measured none of these poses)"
        )
    return (
        f"the centre covariance the calibration's solver weighed it with at {int(known.sum())} of "
        f"{known.size} candidates; {assumed} at the rest (the calibration did not measure them)"
    )


def aim_note(aim: VerdictAim | None, seen: float, needed: float) -> str:
    """How the subset was chosen, for ``verify.json``: ``seen``, the chosen subset's
    ``tolerance_noncentrality``, against the ``needed`` one (both by the noise the choice weighed)."""
    if aim is None:
        return "D-optimal (no tolerance weighed)"
    move = f"a {aim.shift_m * 1e3:g} mm shift and a {np.degrees(aim.turn_rad):.3g} deg turn"
    if seen >= needed:
        return (
            f"sees {move} in its weakest direction with non-centrality {seen:.1f} (the test needs "
            f"{needed:.1f} to flag them 9 times in 10; aimed at {aim.margin:g} times that), then the largest "
            "determinant"
        )
    return (
        f"D-optimal: no subset found sees {move} in every direction as the test needs (at best "
        f"non-centrality {seen:.1f} of {needed:.1f}), so an unmoved scanner's verdict is likely inconclusive"
    )


def _log_det(matrix: FloatArray) -> float:
    sign, value = np.linalg.slogdet(matrix)
    return float(value) if sign > 0 else -np.inf


def tolerance_noncentrality(information: FloatArray, tolerance_m: float, tolerance_rad: float) -> FloatArray:
    """The test's non-centrality for a move of the tolerance in its weakest direction: the
    smaller of a ``tolerance_m`` shift's and a ``tolerance_rad`` turn's where the ``information``
    (..., 6, 6) is least (the smallest eigenvalue of its shift and turn blocks). The verdict says
    ``ok`` only where this reaches the non-centrality the test flags 9 times in 10
    (``drift.detectable_moves``), so the larger, the likelier an unmoved scanner's ``ok``."""
    shift = np.linalg.eigvalsh(information[..., :3, :3])[..., 0] * tolerance_m**2
    turn = np.linalg.eigvalsh(information[..., 3:, 3:])[..., 0] * tolerance_rad**2
    return np.minimum(shift, turn)


def select_waypoints(
    model: DriftModel,
    waypoints: FloatArray,
    count: int,
    visited: NDArray[np.bool_] | None = None,
    *,
    time_of: Callable[[list[int]], float | None] | None = None,
    budget_s: float | None = None,
    centre_covariance_uv_m2: FloatArray | None = None,
    noise_covariance_uv_m2: FloatArray | None = None,
    unusable: NDArray[np.bool_] | None = None,
    aim: VerdictAim | None = None,
) -> Selection:
    """The subset of ``count`` waypoints to visit (all usable ones if fewer), in
    trajectory order; ``visited`` (N,) marks the waypoints the calibration measured (None:
    none), ``centre_covariance_uv_m2`` (N, 2, 2; m^2) the centre covariance the calibration
    weighed each with (NaN or None: unknown, ``DESIGN_SIGMA_UV_M`` assumed),
    ``noise_covariance_uv_m2`` (N, 2, 2; m^2) the part of it a dwell draws anew (NaN or None:
    unknown, all of it), ``unusable`` (N,)
    the waypoints that are no candidates (``active.unusable_waypoints``; None: none). With ``time_of``
    (waypoint indices -> seconds, None if unknown) and ``budget_s``, exchanges first bring the
    subset within the budget (a subset of unknown time is not within it), then improve it inside
    the budget only. With an ``aim`` the exchanges first raise ``tolerance_noncentrality`` (how well
    the test sees a move of the verdict's tolerance in its weakest direction) up to the aim, then
    the determinant: of the subsets with which an unmoved verify can say ``ok``, the one that
    estimates the move best. Where the subset found that way still falls short of what the test
    needs, no ``ok`` is in reach and the choice is the D-optimal one after all."""
    poses = np.asarray(waypoints, dtype=float).reshape(-1, 6)
    seen = np.zeros(len(poses), dtype=bool) if visited is None else np.asarray(visited, dtype=bool)
    crossing = _crosses_plane(model, poses)
    refused = crossing & (False if unusable is None else np.asarray(unusable, dtype=bool))
    usable = np.flatnonzero(crossing & ~refused)
    if len(usable) < MIN_WAYPOINTS:
        unused = (
            f" ({int(refused.sum())} more that are no candidates: no re-fitted centre the "
            "calibration used there, or a pose it visited before)"
            if refused.any()
            else ""
        )
        raise CalibrationError(
            f"only {len(usable)} of the trajectory's {len(poses)} waypoints put the rod through the scan "
            f"plane the calibration describes{unused}: check that the job and the calibration belong to "
            "this cell"
        )
    def recorded(matrices: FloatArray | None) -> FloatArray:
        unknown = np.full((len(poses), 2, 2), np.nan)
        return (unknown if matrices is None else np.asarray(matrices, dtype=float).reshape(-1, 2, 2))[usable]

    whole, drawn = recorded(centre_covariance_uv_m2), recorded(noise_covariance_uv_m2)
    known = np.isfinite(whole).all(axis=(1, 2))
    noise_known = np.isfinite(drawn).all(axis=(1, 2)) & known
    centre = np.where(known[:, None, None], whole, np.eye(2) * DESIGN_SIGMA_UV_M**2)
    noise = np.where(noise_known[:, None, None], drawn, centre)
    information = waypoint_information(model, poses[usable], seen[usable], centre, noise)
    base = np.linalg.inv(model.prior())

    def score(subset: list[int]) -> float:
        return _log_det(base + information[subset].sum(axis=0))

    size = min(count, len(usable))
    needed = 0.0 if aim is None else needed_noncentrality(model, 2 * size)

    def sees(subset: list[int]) -> float:
        """How well ``subset`` sees a move of the aim's tolerance in its weakest direction."""
        if aim is None:
            return 0.0
        return float(tolerance_noncentrality(information[subset].sum(axis=0), aim.shift_m, aim.turn_rad))

    def seconds(subset: list[int]) -> float:
        """The subset's motion and dwell; a subset whose time is unknown (a pose the UR5 model
        cannot reach) counts as over any budget, never as free."""
        if time_of is None or budget_s is None:
            return 0.0
        value = time_of(sorted(int(usable[k]) for k in subset))
        return np.inf if value is None else value

    def exchanged(start: list[int], target: float) -> list[int]:
        """``start`` improved by single swaps: into the budget first, then ``sees`` up to
        ``target`` (0: not weighed), then the determinant."""

        def better(trial: list[int], current: list[int]) -> bool:
            limit = np.inf if budget_s is None else budget_s
            trial_s, current_s = seconds(trial), seconds(current)
            if current_s > limit:  # over budget: any faster subset is better
                return trial_s < current_s - 1e-9
            if trial_s > limit:
                return False
            trial_seen, current_seen = min(sees(trial), target), min(sees(current), target)
            if abs(trial_seen - current_seen) > 1e-9 * max(current_seen, 1.0):
                return trial_seen > current_seen
            return score(trial) > score(current) + 1e-9

        chosen, improved = start, True
        while improved:
            improved = False
            for slot in range(len(chosen)):
                for k in sorted(set(range(len(usable))) - set(chosen)):
                    trial = [*chosen[:slot], k, *chosen[slot + 1:]]
                    if better(trial, chosen):
                        chosen, improved = trial, True
        return chosen

    greedy: list[int] = []
    for _ in range(size):
        scores = [-np.inf if k in greedy else score([*greedy, k]) for k in range(len(usable))]
        greedy.append(int(np.argmax(scores)))
    chosen = exchanged(greedy, 0.0 if aim is None else aim.margin * needed)
    sharpest = sees(chosen)
    if sharpest < needed:  # the verdict cannot vouch with any subset found: the most informative
        chosen = exchanged(greedy, 0.0)
    covariance = np.linalg.inv(base + information[chosen].sum(axis=0))
    std = np.sqrt(np.diag(covariance))
    return Selection(
        indices=sorted(int(usable[k]) for k in chosen),
        candidates=len(usable),
        expected_std_shift_mm=[float(v) for v in std[:3] * 1e3],
        expected_std_turn_deg=[float(v) for v in np.degrees(std[3:])],
        estimated_time_s=time_of(sorted(int(usable[k]) for k in chosen)) if time_of is not None else None,
        centre_noise=centre_noise_note(known, noise_known),
        left_out=[int(i) for i in np.flatnonzero(refused)],
        choice=aim_note(aim, sharpest, needed),
        vouches=None if aim is None else sharpest >= needed,
    )
