"""The drift test: are the rod centres measured now where the active calibration says?

For waypoint i the active transform ``T`` predicts the crossing ``p_i`` (the solver's
measurement model, ``calibration.model``, read through the calibration's range error curve as
the solver predicted its centres); the scanner measured ``m_i`` (fitted as the calibration's
second pass fitted its centres: ``run.two_pass.SecondPassRefit``).  Where the
calibration itself visited that waypoint, the prediction also carries the residual the
calibration saw there (``b_i``: the robot's repeatable absolute-position error at that
pose and what the fit left over), so it is the centre measured back then.  The residual
``d = m - (p + b)`` (2N values) has, if nothing moved, zero mean and the covariance

    S = blockdiag(C_i + R_i) + J_u Sigma_cal J_u^T

with ``C_i`` the centre noise of the measurement and ``R_i`` the robot's share: for a
waypoint the calibration visited, ``C_i`` is only what a dwell draws anew (the rest of the
centre's covariance repeats at the same pose and cancels in ``d``), ``R_i`` the same again
for the calibration's dwell plus the robot's repeatability ``sigma_rep^2 A A^T``; for any
other, ``C_i`` whole and the robot's absolute accuracy ``sigma_robot^2 A A^T``, and the
calibration's own 6x6
covariance propagated with the Jacobian ``J_u`` of those predictions (rows of visited
waypoints are zero there: their prediction does not depend on the solved transform).
The last term correlates the waypoints, so S is whitened as a whole. ``d^T S^-1 d`` is
chi-square with 2N degrees of freedom: above its (1 - alpha) quantile the calibration
has changed, at false-alarm rate alpha.

The correction ``x = (dt, e)`` (the scanner's move since the calibration, in the solver's
parameters: origin shift in base axes, small turn about base axes) is the maximum a
posteriori estimate with the active calibration as the prior, ``x ~ N(0, B)`` (``B``: a
broad prior on how far a bump moves a scanner), from ``d = J x + noise(S)``; its
covariance is ``(J^T S^-1 J + B^-1)^-1``.  Where the calibration's flute phase pass was kept
(``DriftModel.flutes``), ``J`` and the prediction of a move also carry the change of the twist
drill's section offsets the move brings (``verify.helix``), and the move is estimated with the
section model's allowance added at every waypoint the calibration measured (a moved scanner sees
another face, whose model error no longer cancels).  What the correction leaves unexplained is
tested again (chi-square, 2N - 6 degrees of freedom): a change that is not a rigid move
of the scanner (another rod, a bent tool, a robot error) shows there.

The test's power: a move ``delta`` along one parameter direction ``k`` (a shift along a base
axis, a turn about one) moves the residual by ``delta J_k`` (``J``: the crossings' Jacobian at
every waypoint), which makes ``d^T S^-1 d`` non-central chi-square with non-centrality
``delta^2 J_k^T S^-1 J_k``. The smallest move the test flags with probability
``detection_probability`` at its false-alarm rate is ``sqrt(lambda* / J_k^T S^-1 J_k)``,
``lambda*`` the non-centrality at which that probability is reached (``J`` with the helix's
change where flutes are modelled, the weaker of a positive and a negative move). Those are per
base axis; a move about another direction can be seen less: a pure shift ``delta n`` (``n`` a unit
direction) has non-centrality ``delta^2 n^T F_tt n`` with ``F = J^T S^-1 J`` and ``F_tt`` its shift
block, least along the eigenvector of ``F_tt``'s smallest eigenvalue, and a pure turn likewise with
the turn block (``WeakestMoves``). Where the weakest shift or turn is above the tolerance, a test
that flags nothing cannot say the scanner is within it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import block_diag, cho_factor, cho_solve
from scipy.optimize import brentq
from scipy.stats import chi2, ncx2

from lasercal_hw.calibration.model import (
    RANGE_CURVE_BASIS,
    RangeCurveBasis,
    left_jacobian_so3,
    range_error_effect,
    residuals_and_jacobian,
    rod_lines_in_base,
)
from lasercal_hw.models import FloatArray, RodLine
from lasercal_hw.run.flute_phase import FluteShift
from lasercal_hw.verify.helix import HelixChange, moved_transform

_GAUSS_NEWTON_STEPS = 6
_RIGID_PARAMETERS = 6


@dataclass(frozen=True)
class DriftModel:
    """What the test knows before measuring: the active calibration and the noise model."""

    T_base_laser: FloatArray
    covariance: FloatArray
    rod: RodLine
    robot_sigma_m: float
    repeatability_m: float = 0.0001
    false_alarm_rate: float = 0.01
    detection_probability: float = 0.9
    prior_shift_m: float = 0.02
    prior_turn_rad: float = float(np.radians(2.0))
    #: The calibration's range error curve (its coefficients, m, in ``range_curve_basis``) less
    #: the offset its centres were freed of before their fit (``run.two_pass.SecondPassRefit``):
    #: the solver predicted every centre as the scanner reads it through this, and so does the
    #: test (empty: no curve).
    range_curve_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    range_curve_basis: RangeCurveBasis = RANGE_CURVE_BASIS
    #: Where the calibration's flute phase pass was kept: its move of the plain fits, whose
    #: section offsets a moved scanner changes (``verify.helix``; None: no flutes modelled).
    flutes: FluteShift | None = None

    def prior(self) -> FloatArray:
        """Prior covariance (6, 6) of the correction: how far a bump moves a scanner."""
        return np.diag([self.prior_shift_m**2] * 3 + [self.prior_turn_rad**2] * 3)


@dataclass(frozen=True)
class RangeChange:
    """The one range change (every beam reading the same amount longer) that best explains the
    residuals, and the chi-square of what it leaves (``2N - 1`` degrees of freedom): a diagnosis
    of a flagged test, not part of it. A scanner warming up after power-on, or at another
    temperature, reads its ranges so (docs/scanner-model.md, warm-up drift)."""

    offset_m: float
    std_m: float
    remainder_chi_square: float
    remainder_dof: int
    remainder_threshold: float

    @property
    def explains(self) -> bool:
        """True where the change is beyond twice its std and leaves residuals the test accepts."""
        accepted = self.remainder_dof > 0 and self.remainder_chi_square <= self.remainder_threshold
        return accepted and abs(self.offset_m) > 2.0 * self.std_m


@dataclass(frozen=True)
class WeakestMoves:
    """The smallest pure shift and pure turn the test flags with its detection probability in the
    direction where it sees each least (module docstring): what a verdict of ``ok`` promises for a
    move in any direction."""

    shift_m: float
    shift_direction: FloatArray
    turn_rad: float
    turn_axis: FloatArray

    @property
    def shift_mm(self) -> float:
        """The weakest shift (mm)."""
        return self.shift_m * 1e3

    @property
    def turn_deg(self) -> float:
        """The weakest turn (deg)."""
        return float(np.degrees(self.turn_rad))


@dataclass(frozen=True)
class DriftTest:
    """The outcome of the test for N measured waypoints (arrays in waypoint order)."""

    indices: list[int]
    tcp_poses: FloatArray
    predicted_uv_m: FloatArray
    measured_uv_m: FloatArray
    whitened_norm: FloatArray
    chi_square: float
    dof: int
    threshold: float
    p_value: float
    false_alarm_rate: float
    correction: FloatArray
    correction_covariance: FloatArray
    post_fit_chi_square: float
    post_fit_dof: int
    post_fit_threshold: float
    detectable_shift_mm: FloatArray
    detectable_turn_deg: FloatArray
    detection_probability: float
    weakest: WeakestMoves
    range_change: RangeChange | None = None

    @property
    def changed(self) -> bool:
        """True when the measurements contradict the calibration at the stated rate."""
        return self.chi_square > self.threshold

    @property
    def rigid(self) -> bool:
        """False when a rigid scanner move cannot explain the residuals (or untestable: True)."""
        return self.post_fit_dof <= 0 or self.post_fit_chi_square <= self.post_fit_threshold

    @property
    def residual_mm(self) -> FloatArray:
        """Measured minus predicted centre (N, 2) in mm."""
        return (self.measured_uv_m - self.predicted_uv_m) * 1e3

    @property
    def shift_mm(self) -> FloatArray:
        """Estimated move of the scanner origin (base x, y, z) in mm."""
        return self.correction[:3] * 1e3

    @property
    def turn_deg(self) -> FloatArray:
        """Estimated turn of the scanner about the base x, y, z axes in degrees."""
        return np.degrees(self.correction[3:])

    @property
    def std_shift_mm(self) -> FloatArray:
        """Std of each shift component (mm)."""
        return np.sqrt(np.diag(self.correction_covariance)[:3]) * 1e3

    @property
    def std_turn_deg(self) -> FloatArray:
        """Std of each turn component (deg)."""
        return np.degrees(np.sqrt(np.diag(self.correction_covariance)[3:]))

    def shift_norm_mm(self) -> tuple[float, float]:
        """Length of the shift and its std along the shift's direction (mm)."""
        return _norm_and_std(self.correction[:3], self.correction_covariance[:3, :3], 1e3)

    def turn_norm_deg(self) -> tuple[float, float]:
        """Angle of the turn and its std about the turn's axis (deg)."""
        return _norm_and_std(self.correction[3:], self.correction_covariance[3:, 3:], float(np.degrees(1.0)))

    def corrected_T_base_laser(  # noqa: N802 (the transform's name everywhere)
        self, T_base_laser: FloatArray
    ) -> FloatArray:
        """The active transform with the correction applied."""
        return moved_transform(T_base_laser, self.correction)


def _norm_and_std(vector: FloatArray, covariance: FloatArray, unit: float) -> tuple[float, float]:
    length = float(np.linalg.norm(vector))
    if length > 0:
        direction = vector / length
        std = float(np.sqrt(direction @ covariance @ direction))
    else:
        std = float(np.sqrt(np.max(np.linalg.eigvalsh(covariance))))
    return length * unit, std * unit


def detectable_moves(
    jacs: list[FloatArray], noise: tuple[FloatArray, bool], threshold: float, dof: int, probability: float
) -> tuple[FloatArray, WeakestMoves]:
    """The smallest move along each parameter (6,: m, rad) and the weakest shift and turn
    (``WeakestMoves``) that the test with this ``threshold`` flags with ``probability``, from the
    crossings' Jacobians (N, 2, 6 each; with a twist drill's helix a positive and a negative
    move's, the weaker counted) and the factored residual covariance (module docstring)."""
    needed = flagging_noncentrality(threshold, dof, probability)
    rows = [np.asarray(jac, dtype=float).reshape(-1, 6) for jac in jacs]
    informations = [j.T @ cho_solve(noise, j) for j in rows]
    with np.errstate(divide="ignore"):
        per_parameter = np.sqrt(needed / np.min([np.diag(f) for f in informations], axis=0))
    return per_parameter, weakest_moves(informations, needed)


def weakest_moves(informations: list[FloatArray], needed: float) -> WeakestMoves:
    """The weakest shift and turn flagged at the non-centrality ``needed``, from the test's
    information (6, 6) for each way the centres move (with a twist drill's helix a positive and a
    negative move's, the weaker counted)."""

    def weakest(block: slice) -> tuple[float, FloatArray]:
        values, vectors = min((np.linalg.eigh(f[block, block]) for f in informations), key=lambda e: e[0][0])
        size = float(np.sqrt(needed / values[0])) if values[0] > 0 else float("inf")
        return size, vectors[:, 0]

    return WeakestMoves(*weakest(slice(0, 3)), *weakest(slice(3, 6)))


def needed_noncentrality(model: DriftModel, dof: int) -> float:
    """The non-centrality at which the model's test on ``dof`` values flags with its detection
    probability at its false-alarm rate."""
    threshold = float(chi2.ppf(1.0 - model.false_alarm_rate, dof))
    return flagging_noncentrality(threshold, dof, model.detection_probability)


def flagging_noncentrality(threshold: float, dof: int, probability: float) -> float:
    """The non-centrality at which a chi-square with ``dof`` exceeds ``threshold`` with
    ``probability``."""

    def shortfall(noncentrality: float) -> float:
        return float(ncx2.sf(threshold, dof, noncentrality)) - probability

    upper = 1.0
    while shortfall(upper) < 0.0:
        upper *= 2.0
    return float(brentq(shortfall, 1e-9, upper, xtol=1e-6))


def predictions(
    model: DriftModel, tcp_poses: FloatArray, T_base_laser: FloatArray | None = None
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Predicted centres (N, 2) as the scanner reads them (the crossings through the model's
    range error curve, as the solver predicted them), their Jacobian (N, 2, 6) in (dt, e) and
    the slopes (N, 2) of the rod in the scan plane, for ``T_base_laser`` (None: the model's)."""
    T = np.asarray(model.T_base_laser if T_base_laser is None else T_base_laser, dtype=float)
    origins, directions = rod_lines_in_base(np.asarray(tcp_poses, dtype=float).reshape(-1, 6), model.rod)
    zeros = np.zeros((len(origins), 2))
    crossing, jac, slope = residuals_and_jacobian(T[:3, :3], T[:3, 3], origins, directions, zeros)
    if model.range_curve_m.any():
        move, stretch = range_error_effect(crossing, model.range_curve_m, model.range_curve_basis)
        crossing, jac = crossing + move, stretch @ jac
    return crossing, jac, slope


def noise_blocks(
    model: DriftModel,
    slope: FloatArray,
    covariance_uv_m2: FloatArray,
    visited: NDArray[np.bool_],
    noise_covariance_uv_m2: FloatArray | None = None,
) -> FloatArray:
    """``C_i + R_i`` (N, 2, 2) of the module docstring; ``visited`` (N,) is True where the
    calibration saw the waypoint (its residual is part of the prediction).

    ``noise_covariance_uv_m2`` (N, 2, 2): the part of each centre's covariance a new dwell
    draws anew (None: all of it). At a visited waypoint the prediction is the centre the
    calibration measured there from the same pose and view: the rest of the covariance (the
    rod's shape, blends, the range error across the arc) is in both centres and cancels;
    what a dwell draws anew is counted for both dwells."""
    centre = np.asarray(covariance_uv_m2, dtype=float)
    noise = centre if noise_covariance_uv_m2 is None else np.asarray(noise_covariance_uv_m2, dtype=float)
    revisit = 2.0 * noise
    spread = np.eye(2) + slope[:, :, None] * slope[:, None, :]
    robot_var = np.where(visited, model.repeatability_m**2, model.robot_sigma_m**2)
    blocks = np.where(visited[:, None, None], revisit, centre)
    return blocks + robot_var[:, None, None] * spread


def residual_covariance(
    model: DriftModel,
    jac: FloatArray,
    slope: FloatArray,
    covariance_uv_m2: FloatArray,
    visited: NDArray[np.bool_],
    noise_covariance_uv_m2: FloatArray | None = None,
) -> FloatArray:
    """``S`` (2N, 2N) of the module docstring."""
    j = (jac * (~visited)[:, None, None]).reshape(-1, 6)
    blocks = noise_blocks(model, slope, covariance_uv_m2, visited, noise_covariance_uv_m2)
    return block_diag(*blocks) + j @ np.asarray(model.covariance, dtype=float) @ j.T


def run_drift_test(
    model: DriftModel,
    indices: list[int],
    tcp_poses: FloatArray,
    measured_uv_m: FloatArray,
    covariance_uv_m2: FloatArray,
    recorded_residual_uv_m: FloatArray | None = None,
    noise_covariance_uv_m2: FloatArray | None = None,
) -> DriftTest:
    """The chi-square test and the correction for N >= 1 measured waypoints.

    ``recorded_residual_uv_m`` (N, 2): measured minus predicted centre of the calibration
    at each waypoint, NaN where it did not visit it (None: it visited none of them).
    """
    measured = np.asarray(measured_uv_m, dtype=float).reshape(-1, 2)
    poses = np.asarray(tcp_poses, dtype=float).reshape(-1, 6)
    n = len(measured)
    recorded = (
        np.full((n, 2), np.nan) if recorded_residual_uv_m is None else np.asarray(recorded_residual_uv_m)
    )
    visited = np.isfinite(recorded).all(axis=1)
    crossing, jac, slope = predictions(model, poses)
    predicted = crossing + np.where(visited[:, None], recorded, 0.0)
    total = residual_covariance(model, jac, slope, covariance_uv_m2, visited, noise_covariance_uv_m2)
    factor = cho_factor(total)
    d = (measured - predicted).reshape(-1)
    chi_square = float(d @ cho_solve(factor, d))
    dof = d.size
    blocks = total.reshape(n, 2, n, 2)[np.arange(n), :, np.arange(n)]
    per_waypoint = np.array(
        [float(r @ np.linalg.solve(b, r)) for r, b in zip(d.reshape(-1, 2), blocks, strict=True)]
    )
    helix = HelixChange.none(n) if model.flutes is None else HelixChange.of(model.flutes, poses)
    move_noise = _move_noise(model, total, factor, visited)
    correction, correction_cov, post_fit = _correction(
        model, poses, measured - (predicted - crossing), move_noise, helix.jacobian
    )
    post_dof = dof - _RIGID_PARAMETERS
    alpha = model.false_alarm_rate
    threshold = float(chi2.ppf(1.0 - alpha, dof))
    detectable, weakest = detectable_moves(
        [jac + helix.forward, jac + helix.backward], factor, threshold, dof, model.detection_probability
    )
    return DriftTest(
        indices=list(indices),
        tcp_poses=poses,
        predicted_uv_m=predicted,
        measured_uv_m=measured,
        whitened_norm=np.sqrt(per_waypoint),
        chi_square=chi_square,
        dof=dof,
        threshold=threshold,
        p_value=float(chi2.sf(chi_square, dof)),
        false_alarm_rate=alpha,
        correction=correction,
        correction_covariance=correction_cov,
        post_fit_chi_square=post_fit,
        post_fit_dof=post_dof,
        post_fit_threshold=float(chi2.ppf(1.0 - alpha, post_dof)) if post_dof > 0 else float("inf"),
        detectable_shift_mm=detectable[:3] * 1e3,
        detectable_turn_deg=np.degrees(detectable[3:]),
        detection_probability=model.detection_probability,
        weakest=weakest,
        range_change=_range_change(crossing, d, factor, alpha),
    )


def _range_change(
    crossing: FloatArray, d: FloatArray, factor: tuple[FloatArray, bool], alpha: float
) -> RangeChange:
    """``RangeChange`` of the residuals ``d`` (2N,): a range change moves each rod centre along
    its bearing (the ``crossing``, (N, 2)), weighed with ``S``."""
    bearings = (crossing / np.linalg.norm(crossing, axis=1)[:, None]).reshape(-1)
    information = float(bearings @ cho_solve(factor, bearings))
    offset_m = float(bearings @ cho_solve(factor, d)) / information
    remainder = d - offset_m * bearings
    dof = d.size - 1
    return RangeChange(
        offset_m=offset_m,
        std_m=float(np.sqrt(1.0 / information)),
        remainder_chi_square=float(remainder @ cho_solve(factor, remainder)),
        remainder_dof=dof,
        remainder_threshold=float(chi2.ppf(1.0 - alpha, dof)) if dof > 0 else float("inf"),
    )


def _move_noise(
    model: DriftModel, total: FloatArray, factor: tuple[FloatArray, bool], visited: NDArray[np.bool_]
) -> tuple[FloatArray, bool]:
    """The factored covariance the move is estimated and its remainder tested with: ``S``, and
    with flutes the section model's allowance (``FluteShift.allowance_uv_m2``) at every waypoint
    the calibration measured: a moved scanner sees another face of the section, whose model error
    no longer cancels against the calibration's residual there (elsewhere the centre's own
    covariance holds it)."""
    if model.flutes is None:
        return factor
    allowance = np.where(visited[:, None, None], model.flutes.allowance_uv_m2(), 0.0)
    return cho_factor(total + block_diag(*allowance))


def _correction(
    model: DriftModel,
    poses: FloatArray,
    target_uv_m: FloatArray,
    noise: tuple[FloatArray, bool],
    helix: FloatArray,
) -> tuple[FloatArray, FloatArray, float]:
    """MAP correction (6,), its covariance (6, 6) and the data part of the objective at it:
    Gauss-Newton on ``|c(x) - target|^2_S + x^T B^-1 x`` with ``c`` the crossings of the
    moved transform plus ``helix @ x`` (the section offsets' change, ``verify.helix``: zeros
    without flutes) and ``target`` the measured centres less the recorded residuals; converges
    in a few steps for bumps."""
    prior_information = np.linalg.inv(model.prior())
    x = np.zeros(6)

    def linearised(x: FloatArray) -> tuple[FloatArray, FloatArray]:
        crossing, jac, _ = predictions(model, poses, moved_transform(model.T_base_laser, x))
        jac[:, :, 3:] = jac[:, :, 3:] @ left_jacobian_so3(x[3:])
        crossing, jac = crossing + helix @ x, jac + helix
        return (target_uv_m - crossing).reshape(-1), jac.reshape(-1, 6)

    for _ in range(_GAUSS_NEWTON_STEPS):
        d, j = linearised(x)
        information = j.T @ cho_solve(noise, j) + prior_information
        step = np.linalg.solve(information, j.T @ cho_solve(noise, d) - prior_information @ x)
        x = x + step
        if np.max(np.abs(step)) < 1e-10:
            break
    d, j = linearised(x)
    covariance = np.linalg.inv(j.T @ cho_solve(noise, j) + prior_information)
    return x, covariance, float(d @ cho_solve(noise, d))
