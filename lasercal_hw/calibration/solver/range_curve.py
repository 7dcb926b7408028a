"""The scanner's range error curve over distance: how many terms the waypoints pin down before the fit,
which stay significant after it (a t-test on the fit's own residuals), the lower curve to restart
from when a term is left out, and the curve reported in the result (``RangeOffset``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import special

from lasercal_hw.calibration.model import (
    RANGE_CURVE_BASIS,
    RANGE_CURVE_REFERENCE_M,
    plane_crossing,
    range_curve_variable,
    range_error_basis,
    range_error_m,
)
from lasercal_hw.calibration.result import RangeErrorPoint, RangeOffset
from lasercal_hw.calibration.solver.data import _Data
from lasercal_hw.calibration.solver.extras import _crb_std, _extended_fisher, _Extras
from lasercal_hw.calibration.solver.fit import _fit
from lasercal_hw.calibration.solver.formatting import _list
from lasercal_hw.calibration.solver.observability import _require_observable
from lasercal_hw.calibration.solver.options import SolverOptions
from lasercal_hw.calibration.solver.residuals import _degrees_of_freedom, _residual_scale
from lasercal_hw.errors import CalibrationError
from lasercal_hw.geometry import FloatArray


def _significant_terms(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    used: np.ndarray,
    opts: SolverOptions,
    extras: _Extras,
) -> tuple[bool, _Extras]:
    """Keep the range error curve's highest term only when the data show it: a t-test of its
    coefficient against the std the fit's own residuals give it (the Cramér-Rao std times the
    residuals' scale, ``sqrt(reduced chi-square)``), at the two-sided level of
    ``auto_range_offset_min_sigmas`` normal std, on the fit's degrees of freedom. This is the
    F-test of the chi-square the term removes: it does not depend on the stated noise's level,
    so conservative centre covariances do not drop a term the residuals need (the fit without
    it then gates good waypoints out). Estimating a parameter that is not there costs the pose
    precision. The offset itself is kept when asked for (not ``auto``). Returns whether the
    curve stays as it is, and the extras to go on with (one term fewer)."""
    terms = extras.range_terms
    if terms == 1 and opts.estimate_range_offset is True:
        return True, extras
    std = float(_crb_std(_extended_fisher(rotation, translation, data, used, opts, extras))[-1])
    std *= _residual_scale(rotation, translation, data, used, opts, extras)
    value = float(data.range_curve_m[terms - 1])
    dof = _degrees_of_freedom(used, extras)
    if abs(value) >= _t_quantile(opts.auto_range_offset_min_sigmas, dof) * std:
        return True, extras
    name, unit, scale = _TERM_UNITS[terms - 1]
    note = f"scanner range {name} {value * scale:+.3g} ± {std * scale:.2g} {unit} is not significant (auto): "
    note += "left out"
    notes = "; ".join(n for n in (extras.offset_note, note) if n)
    return False, replace(extras, range_terms=terms - 1, offset_note=notes)


def _lower_curve(
    rotation: FloatArray, translation: FloatArray, data: _Data, used: np.ndarray, terms: int
) -> FloatArray:
    """The start of the fit with ``terms`` terms when a higher one is left out: the curve of
    that many terms closest (least squares) to the fitted one at the used crossings'
    distances. Not the fitted curve cut short: its terms are powers of ``ln(d / 1 m)``, and
    crossings all on one side of 1 m make them large and cancelling (a 7-waypoint job at
    0.3-0.55 m fitted -203, -1092, -2112, -1736, -517 mm), so the cut curve is hundreds of
    mm off where the rod was seen and the robust fit from there rejects good waypoints."""
    if not terms:
        return np.zeros(0)
    crossing, _, _ = plane_crossing(rotation, translation, data.origins[used], data.directions[used])
    distances_m = np.linalg.norm(crossing, axis=1)
    fitted, _ = range_error_m(data.range_curve_m, distances_m)
    lower, *_ = np.linalg.lstsq(range_error_basis(distances_m, terms), fitted, rcond=None)
    return lower


def _fullest_fit_scale(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    usable: np.ndarray,
    start: np.ndarray,
    opts: SolverOptions,
    extras: _Extras,
) -> float:
    """The residuals' scale against the stated noise (``_residual_scale``) of the robust fit
    with every term of the range error curve: the fullest model gives the noise's level
    without the bias of a term left out, so the precision gate judges each term by the std
    the data give it, not by the stated (often conservative) noise. 1 when that fit fails."""
    fullest = replace(extras, range_terms=opts.max_range_terms)
    try:
        rotation, translation, fitted, used, _ = _fit(
            rotation, translation, data, usable, start, True, opts, fullest
        )
    except CalibrationError:
        return 1.0
    return _residual_scale(rotation, translation, fitted, used, opts, fullest)


def _t_quantile(normal_sigmas: float, dof: int) -> float:
    """The Student-t quantile on ``dof`` degrees of freedom with the two-sided tail of
    ``normal_sigmas`` normal std (the normal quantile itself when ``dof`` is not positive)."""
    if dof <= 0:
        return normal_sigmas
    return float(special.stdtrit(dof, special.ndtr(normal_sigmas)))


#: Name, unit and scale from SI of each range-curve term in messages (``x = ln(d / 1 m)``).
_TERM_UNITS = tuple(
    (name, "mm" if not k else f"mm/x{'^' + str(k) if k > 1 else ''}", 1e3)
    for k, name in enumerate(("offset", "slope", "curvature", "cubic term", "quartic term"))
)


def _range_terms_wanted(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    usable: np.ndarray,
    opts: SolverOptions,
    noise_scale: float = 1.0,
) -> tuple[int, str]:
    """How many terms of the range error curve to estimate, and the note when one is left
    out: the most terms whose highest term passes, a term passing when the Cramér-Rao std of
    what it adds to the error over the crossings is within ``auto_range_offset_max_std_m``
    (the offset must be observable when asked for: ``DegenerateDataError`` otherwise). A
    term may pass where a lower one does not: the offset trades against the translation
    along the bearings, and a curve whose slope the distances pin down is estimated with its
    offset, the offset's std then carried into the pose's (a 10-waypoint quick run on the
    physical scanner: offset 2.4 mm over the limit, slope within it; without both, its
    +-10 mm range error failed the outlier test). What it adds is its coefficient's std times half the
    crossings' span in ln d to its power: the highest term's coefficient does not depend on
    where the curve's reference lies (the lower terms take the rest), so a trajectory whose
    crossings all lie on one side of 1 m is judged by its own span, not by an extrapolation.
    ``noise_scale``: the residuals' scale against the stated noise (``_fullest_fit_scale``),
    which the std is multiplied by."""
    if opts.estimate_range_offset is False:
        return 0, ""
    crossing, _ = data.predicted(rotation, translation)
    distances_m = np.linalg.norm(crossing[usable], axis=1)
    reach = max(0.5 * float(np.ptp(range_curve_variable(distances_m)[0])), 1e-3)
    terms = 1 if opts.estimate_range_offset is True else 0
    left_out: list[tuple[int, float]] = []
    for wanted in range(1, opts.max_range_terms + 1):
        trial = _Extras(range_terms=wanted)
        fisher = _extended_fisher(rotation, translation, data, usable, opts, trial)
        if wanted == 1 and opts.estimate_range_offset is True:
            _require_observable(fisher, opts, trial)
        effect_std_m = float(_crb_std(fisher)[-1]) * reach ** (wanted - 1) * noise_scale
        if effect_std_m <= opts.auto_range_offset_max_std_m:
            terms = wanted
        else:
            left_out.append((wanted, effect_std_m))
    left_out = [(wanted, std) for wanted, std in left_out if wanted > terms]
    if not left_out:
        return terms, ""
    wanted, effect_std_m = left_out[0]
    name = _TERM_UNITS[wanted - 1][0]
    return terms, (
        f"scanner range {name} not estimated (auto): the Cramér-Rao std of what it adds "
        f"to the range error would be {effect_std_m * 1e3:.2g} mm (limit "
        f"{opts.auto_range_offset_max_std_m * 1e3:g} mm); spread the crossings' distances from the scanner "
        "more widely (0.3 m or more apart, near and far) to see it"
    )


def _range_offset(
    data: _Data, extras: _Extras, covariance: FloatArray, opts: SolverOptions, distances_m: FloatArray
) -> RangeOffset | None:
    """The estimated range error curve (the applied offset added back), its std, and its
    values over the distances the crossings span (the scanner's health figure)."""
    if not extras.offset:
        return None
    terms = extras.range_terms
    curve = data.range_curve_m[:terms].copy()
    curve[0] += opts.range_offset_applied_m
    block = covariance[-terms:, -terms:]
    std = np.sqrt(np.clip(np.diag(block), 0.0, None))
    grid = np.linspace(float(distances_m.min()), float(distances_m.max()), 5)
    basis = range_error_basis(grid, terms)
    values = range_error_m(curve, grid)[0]
    value_std = np.sqrt(np.clip(np.einsum("nk,kl,nl->n", basis, block, basis), 0.0, None))
    dense = np.linspace(grid[0], grid[-1], 50)
    return RangeOffset(
        offset_mm=float(curve[0]) * 1e3,
        std_mm=float(std[0]) * 1e3,
        reference_m=RANGE_CURVE_REFERENCE_M,
        basis=RANGE_CURVE_BASIS,
        terms_mm=_list(curve * 1e3),
        terms_std_mm=_list(std * 1e3),
        curve=[
            RangeErrorPoint(distance_m=float(d), error_mm=float(e) * 1e3, std_mm=float(s) * 1e3)
            for d, e, s in zip(grid, values, value_std, strict=True)
        ],
        worst_mm=float(np.max(np.abs(range_error_m(curve, dense)[0]))) * 1e3,
    )
