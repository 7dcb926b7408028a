"""The entry point ``solve``: the package's pipeline step by step (validate -> closed-form linear start
-> observability -> which extras -> robust fit with outlier rejection, or the paper's problem ->
the range curve's significant terms -> divergence check -> result)."""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from typing import Literal

import numpy as np

from lasercal_hw.calibration.initial import linear_initial_pose
from lasercal_hw.calibration.paper import solve_paper
from lasercal_hw.calibration.plausible import check_physical
from lasercal_hw.calibration.result import CalibrationResult
from lasercal_hw.calibration.solver.assemble import _result
from lasercal_hw.calibration.solver.choice import _extras
from lasercal_hw.calibration.solver.data import (
    MIN_WAYPOINTS,
    _arrays,
    _check_rod_directions,
    _usable_by_incidence,
)
from lasercal_hw.calibration.solver.fit import _check_not_diverged, _fit, _rejected
from lasercal_hw.calibration.solver.observability import _check_observability
from lasercal_hw.calibration.solver.options import SolverOptions
from lasercal_hw.calibration.solver.range_curve import _fullest_fit_scale, _lower_curve, _significant_terms
from lasercal_hw.errors import CalibrationError, DegenerateDataError
from lasercal_hw.models import Observation, RodLine

logger = logging.getLogger(__name__)


def solve(
    observations: Sequence[Observation],
    rod: RodLine,
    *,
    robust: bool = True,
    options: SolverOptions | None = None,
    formulation: Literal["ours", "paper"] | None = None,
) -> CalibrationResult:
    """Estimate ``T_base_laser`` from rod observations; see the module docstring.

    Raises ``DegenerateDataError`` when the data cannot determine all six degrees of
    freedom, ``ConfigError`` for invalid covariances, ``CalibrationError`` when too many
    waypoints are outliers.
    """
    started = time.perf_counter()
    opts = options or SolverOptions()
    if formulation is not None:
        opts = opts.model_copy(update={"formulation": formulation})
    data = _arrays(observations, check_physical(observations), rod, opts)
    _check_rod_directions(data.directions, opts)
    weights = 1.0 / np.sqrt(0.5 * np.trace(data.covariance, axis1=1, axis2=2))
    initial = linear_initial_pose(data.origins, data.directions, data.centres, weights)
    rotation, translation = initial.rotation, initial.translation
    usable, outliers = _usable_by_incidence(rotation, translation, data, opts)
    _check_observability(rotation, translation, data, usable, opts, stage="initial")
    extras = _extras(rotation, translation, data, usable, opts)

    if opts.formulation == "paper":
        paper = solve_paper(data.origins[usable], data.directions[usable], data.centres[usable])
        rotation, translation = paper.rotation, paper.translation_m
        used, converged, evaluations, message = usable, paper.converged, paper.evaluations, paper.message
    else:
        agreeing = usable & initial.agreeing
        # The linear start knows no range error: with a curve to estimate, waypoints that a
        # range error moves along their bearings disagree with it, and a robust fit started
        # without them extrapolates the curve to them (a default run on the physical scanner
        # model: 8 of 20 near waypoints then failed the outlier test by 7-200 sigma).
        agreed = robust and agreeing.sum() >= MIN_WAYPOINTS and not extras.offset
        start = agreeing if agreed else usable
        if robust and 0 < extras.range_terms < opts.max_range_terms:
            scale = _fullest_fit_scale(rotation, translation, data, usable, start, opts, extras)
            extras = _extras(rotation, translation, data, usable, opts, scale)
        rotation, translation, data, used, evaluations = _fit(
            rotation, translation, data, usable, start, robust, opts, extras
        )
        while extras.offset:
            kept, extras = _significant_terms(rotation, translation, data, used, opts, extras)
            if kept:
                break
            curve = _lower_curve(rotation, translation, data, used, extras.range_terms)
            rotation, translation, data, used, more = _fit(
                rotation, translation, data.with_line(data.rod, curve), usable, used, robust, opts, extras
            )
            evaluations += more
        outliers += _rejected(rotation, translation, data, usable & ~used, opts)
        converged, message = True, "converged"
    _check_not_diverged(rotation, translation, data, used)
    try:
        result = _result(rotation, translation, data, used, outliers, opts, robust, extras)
    except DegenerateDataError as exc:
        if opts.formulation != "paper":
            raise
        raise CalibrationError(
            f"the paper formulation ended at an unusable pose ({message}; {evaluations} evaluations): {exc}"
        ) from exc
    result.provenance.converged = converged
    result.provenance.iterations = evaluations
    result.provenance.message = message
    result.provenance.solve_time_s = time.perf_counter() - started
    logger.info(
        "solved (%s): %d of %d waypoints used, RMS residual %.2f mm, %d evaluations, %.1f ms",
        opts.formulation,
        result.waypoints_used,
        len(observations),
        result.rms_residual_mm,
        evaluations,
        result.provenance.solve_time_s * 1e3,
    )
    return result
