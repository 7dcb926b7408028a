"""The observations as the solver's arrays (``_Data``: rod lines in the base frame, centres, covariances)
and the checks on them before any fit: enough waypoints, finite and well-formed values, rod axes not
all parallel, rods that cross the scan plane steeply enough (``_usable_by_incidence``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from lasercal_hw.calibration.model import plane_crossing, range_error_m, rod_lines_of_transforms
from lasercal_hw.calibration.result import Outlier
from lasercal_hw.calibration.solver.formatting import _finite, _fmt
from lasercal_hw.calibration.solver.options import SolverOptions
from lasercal_hw.errors import ConfigError, DegenerateDataError
from lasercal_hw.geometry import FloatArray, pose_to_matrix
from lasercal_hw.models import Observation, RodLine

MIN_WAYPOINTS = 5


@dataclass
class _Data:
    """The observations as arrays, rod lines in the base frame (for the current rod line
    ``rod`` and range error curve ``range_curve_m``: ``with_line`` moves them)."""

    index: np.ndarray
    origins: FloatArray
    directions: FloatArray
    centres: FloatArray
    covariance: FloatArray
    tcp_transforms: FloatArray
    rod: RodLine
    nominal_rod: RodLine
    range_curve_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    #: The part of each centre's covariance another dwell draws anew (N, 2, 2), NaN where the
    #: observation did not say (``Observation.noise_covariance_uv_m2``): recorded, not weighed.
    noise_covariance: FloatArray = field(default_factory=lambda: np.zeros((0, 2, 2)))

    def with_line(self, rod: RodLine, range_curve_m: FloatArray) -> _Data:
        """The same observations for another rod line and range error curve."""
        origins, directions = _lines(self.tcp_transforms, rod)
        return replace(self, origins=origins, directions=directions, rod=rod, range_curve_m=range_curve_m)

    def predicted(self, rotation: FloatArray, translation: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Where the centres should be seen (N, 2), with the range error, and the slopes."""
        crossing, slope, _ = plane_crossing(rotation, translation, self.origins, self.directions)
        if self.range_curve_m.any():
            distance = np.linalg.norm(crossing, axis=1)
            crossing = crossing * (1.0 + range_error_m(self.range_curve_m, distance)[0] / distance)[:, None]
        return crossing, slope


def _lines(tcp_transforms: FloatArray, rod: RodLine) -> tuple[FloatArray, FloatArray]:
    rotations = tcp_transforms[:, :3, :3]
    return rotations @ np.asarray(rod.origin_m, dtype=float) + tcp_transforms[
        :, :3, 3
    ], rotations @ rod.unit_direction()


def _arrays(
    observations: Sequence[Observation], table: FloatArray, rod: RodLine, opts: SolverOptions
) -> _Data:
    """The solver's arrays from the observations and their (N, 8) pose and centre rows."""
    n = len(observations)
    if n < MIN_WAYPOINTS:
        raise DegenerateDataError(
            f"only {n} waypoint(s); at least {MIN_WAYPOINTS} with different rod orientations are needed "
            "(each gives 2 equations for 6 unknowns): record more waypoints"
        )
    index = np.array([o.index for o in observations])
    poses, centres = table[:, :6], table[:, 6:]
    default = np.eye(2) * opts.default_sigma_uv_m**2
    covariance = np.array(
        [default if o.covariance_uv_m2 is None else o.covariance_uv_m2 for o in observations], dtype=float
    )
    misshapen = covariance.shape != (n, 2, 2) or any(
        np.shape(observations[row].tcp_pose) != (6,) or np.shape(observations[row].centre_uv_m) != (2,)
        for row in np.flatnonzero(np.isnan(table).all(axis=1))
    )
    if misshapen:
        raise ConfigError(
            "each observation needs a 6-element TCP pose, a 2-element centre and a 2x2 covariance"
        )
    finite = np.isfinite(poses).all(axis=1) & np.isfinite(centres).all(axis=1)
    finite &= np.isfinite(covariance).all(axis=(1, 2))
    if not finite.all():
        bad = ", ".join(str(i) for i in index[~finite][:10])
        raise DegenerateDataError(
            f"waypoint(s) {bad} contain NaN or infinite values: re-record or remove those waypoints"
        )
    rod_direction = np.asarray(rod.direction, dtype=float)
    if not (np.isfinite(rod_direction).all() and np.linalg.norm(rod_direction) > 1e-9):
        raise ConfigError(f"rod axis direction {rod_direction.tolist()} is not a usable direction")
    det = covariance[:, 0, 0] * covariance[:, 1, 1] - covariance[:, 0, 1] ** 2
    bad_cov = ~((covariance[:, 0, 0] > 0) & (det > 0))
    if bad_cov.any():
        raise ConfigError(
            f"centre covariance of waypoint {index[bad_cov][0]} is not positive definite: "
            "give positive sigma_u, sigma_v"
        )
    transforms = pose_to_matrix(poses)
    origins, directions = rod_lines_of_transforms(transforms, rod)
    unknown = np.full((2, 2), np.nan)
    noise = np.array(
        [unknown if o.noise_covariance_uv_m2 is None else o.noise_covariance_uv_m2 for o in observations],
        dtype=float,
    ).reshape(n, 2, 2)
    return _Data(
        index, origins, directions, centres, covariance, transforms, rod, rod, noise_covariance=noise
    )


def _check_rod_directions(directions: FloatArray, opts: SolverOptions) -> None:
    mean = directions.mean(axis=0)
    mean /= np.linalg.norm(mean)
    spread_deg = float(np.degrees(np.arccos(np.clip(directions @ mean, -1.0, 1.0))).max())
    if spread_deg <= opts.parallel_tolerance_deg:
        raise DegenerateDataError(
            f"all rod axes are parallel (within {spread_deg:.2f} deg, along base {_fmt(mean)}): the "
            "translation along the rod axis and the tilt of the scan plane are not observable; vary "
            "the tool orientation, tilting the rod 10-20 deg about two different axes across the waypoints"
        )


def _usable_by_incidence(
    rotation: FloatArray, translation: FloatArray, data: _Data, opts: SolverOptions
) -> tuple[np.ndarray, list[Outlier]]:
    """Waypoints whose rod crosses the (initial) scan plane steeply enough to be used."""
    normal = rotation[:, 2]
    incidence_deg = np.degrees(np.arcsin(np.clip(np.abs(data.directions @ normal), 0.0, 1.0)))
    usable = incidence_deg >= opts.min_incidence_deg
    if usable.sum() < MIN_WAYPOINTS:
        raise DegenerateDataError(
            f"rod axes lie nearly in the scan plane (steepest crossing {incidence_deg.max():.1f} deg, "
            f"{int(usable.sum())} waypoint(s) above {opts.min_incidence_deg:g} deg): the crossing point "
            "along the rod is not observable; point the rod through the scan plane at 30 deg or more"
        )
    crossing, _, _ = plane_crossing(rotation, translation, data.origins, data.directions)
    offset_mm = np.linalg.norm(crossing - data.centres, axis=1) * 1e3
    outliers = [
        Outlier(
            index=int(data.index[i]),
            residual_mm=_finite(offset_mm[i]),
            reason=f"rod axis only {incidence_deg[i]:.1f} deg from the scan plane "
            f"(minimum {opts.min_incidence_deg:g} deg)",
        )
        for i in np.flatnonzero(~usable)
    ]
    return usable, outliers
