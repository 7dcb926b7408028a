"""Solve for ``T_base_laser`` from rod observations.

Pipeline (see docs/solver.md): validate -> closed-form linear start (``calibration/initial``) ->
robust nonlinear least squares on the whitened in-plane residual (``calibration/model``) with
iterated outlier rejection -> plain least squares on the inliers -> covariance, Cramér-Rao
bound and observability check.  ``formulation="paper"`` runs the paper's own problem
(``calibration/paper``) instead and reports it with the same diagnostics.

The outlier test is in ``fit``'s docstring.

Modules, one job each (names with a leading underscore are this package's own, not for its
callers): ``pipeline`` (the entry point ``solve``, the steps in order), ``options``
(``SolverOptions``), ``data`` (the observations as arrays, their checks, the incidence test),
``choice`` (which parameters besides the pose to estimate), ``extras`` (those parameters and the
information with them), ``fit`` (robust fit, outlier rejection, divergence check), ``residuals``
(residuals against the stated noise, reduced chi-square), ``observability`` (what the waypoints
determine, advice in words), ``range_curve`` (the range error curve's terms, their significance,
the reported curve), ``axis`` (the rod axis: deviation, std, prior, advice, estimate), ``assemble``
(the ``CalibrationResult``) and ``formatting`` (numbers into words and lists).
"""

from __future__ import annotations

from lasercal_hw.calibration.solver.axis import axis_deviation
from lasercal_hw.calibration.solver.options import SolverOptions
from lasercal_hw.calibration.solver.pipeline import solve

__all__ = ["SolverOptions", "axis_deviation", "solve"]
