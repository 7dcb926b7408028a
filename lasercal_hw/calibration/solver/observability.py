"""Whether the waypoints determine the pose (and the extras): the Fisher information's singular values,
a refusal naming the lost direction with what to change in the trajectory, and notes on weak ones."""

from __future__ import annotations

import numpy as np

from lasercal_hw.calibration.model import fisher_information, plane_crossing
from lasercal_hw.calibration.result import Observability
from lasercal_hw.calibration.solver.axis import _axis_advice
from lasercal_hw.calibration.solver.data import _Data
from lasercal_hw.calibration.solver.extras import _crb_std, _Extras
from lasercal_hw.calibration.solver.formatting import _fmt
from lasercal_hw.calibration.solver.options import SolverOptions
from lasercal_hw.errors import DegenerateDataError
from lasercal_hw.geometry import FloatArray


def _check_observability(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    used: np.ndarray,
    opts: SolverOptions,
    *,
    stage: str,
) -> tuple[FloatArray, Observability]:
    """Fisher information of the used waypoints; refuse if a direction is not observable."""
    origins, directions = data.origins[used], data.directions[used]
    fisher = fisher_information(
        rotation, translation, origins, directions, data.covariance[used], opts.robot_sigma_m
    )
    crossing, _, _ = plane_crossing(rotation, translation, origins, directions)
    lever_m = max(0.1, float(np.sqrt(np.mean(np.sum(crossing**2, axis=1)))))
    scale = np.array([1.0, 1.0, 1.0, 1.0 / lever_m, 1.0 / lever_m, 1.0 / lever_m])
    eigenvalues, vectors = np.linalg.eigh(fisher * np.outer(scale, scale))
    singular = np.sqrt(np.clip(eigenvalues, 0.0, None))[::-1]
    vectors = vectors[:, ::-1]
    ratio = float(singular[-1] / singular[0]) if singular[0] > 0 else 0.0
    if not np.isfinite(ratio) or ratio < opts.min_condition_ratio:
        lost = [
            _describe_direction(vectors[:, k], lever_m, translation)
            for k in range(6)
            if not singular[k] > opts.min_condition_ratio * singular[0]
        ]
        what = f"{lost[0]} is" if len(lost) == 1 else f"{len(lost)} directions ({'; '.join(lost)}) are"
        raise DegenerateDataError(
            f"{what} not observable from these waypoints ({stage} singular-value ratio {ratio:.1e}); "
            f"{_advice(vectors[:, -1], rotation, directions, crossing)}"
        )
    notes = [
        f"weakly observable ({singular[k] / singular[0]:.1e} of the strongest): "
        f"{_describe_direction(vectors[:, k], lever_m, translation)}"
        for k in range(6)
        if singular[k] / singular[0] < opts.weak_condition_ratio
    ]
    observability = Observability(
        lever_m=lever_m,
        singular_values=[float(s) for s in singular],
        condition_ratio=ratio,
        weakest_direction=_describe_direction(vectors[:, -1], lever_m, translation),
        notes=notes,
    )
    return fisher, observability


def _describe_direction(vector: FloatArray, lever_m: float, translation: FloatArray) -> str:
    """Name a parameter direction (dt, lever * e) in words: a translation, or a rotation
    about a base-frame axis through a point (the scanner turning about that axis)."""
    trans, rot = vector[:3], vector[3:] / lever_m
    if np.linalg.norm(vector[3:]) < 0.3:
        return f"translation along base {_fmt(trans / np.linalg.norm(trans))}"
    # A whole-body rotation e about an axis through c moves the scanner origin by e x (t - c).
    axis = rot / np.linalg.norm(rot)
    moment = np.cross(rot, translation) - trans
    foot = np.cross(moment, rot) / (rot @ rot)
    point = foot + ((translation - foot) @ axis) * axis
    text = f"rotation about base axis {_fmt(axis)} through ({', '.join(f'{v:.2f}' for v in point)}) m"
    slide = (trans @ axis) / np.linalg.norm(rot)
    if abs(slide) > 0.1 * lever_m:
        text += f" with {abs(slide):.2f} m/rad translation along it"
    return text


def _advice(vector: FloatArray, rotation: FloatArray, directions: FloatArray, crossing: FloatArray) -> str:
    """What to change in the trajectory so that the given direction becomes observable."""
    spread_mm = 1e3 * float(np.sqrt(np.mean(np.sum((crossing - crossing.mean(axis=0)) ** 2, axis=1))))
    mean_rod = directions.mean(axis=0) / max(np.linalg.norm(directions.mean(axis=0)), 1e-12)
    tilt_deg = float(np.degrees(np.arccos(np.clip(directions @ mean_rod, -1.0, 1.0))).max())
    spread = (
        f"spread the crossing points over the scan plane (now within {spread_mm:.0f} mm RMS; "
        "use different bearings and distances)"
    )
    tilt = (
        f"tilt the rod more between waypoints (now within {tilt_deg:.1f} deg; "
        "use 10-20 deg about two different axes)"
    )
    if spread_mm < 50.0:
        return spread
    if tilt_deg < 5.0:
        return tilt
    trans, rot = vector[:3], vector[3:]
    normal = rotation[:, 2]
    if np.linalg.norm(trans) >= np.linalg.norm(rot):
        unit = trans / np.linalg.norm(trans)
        return tilt if abs(unit @ normal) > 0.7 or abs(unit @ mean_rod) > 0.7 else spread
    unit = rot / np.linalg.norm(rot)
    if abs(unit @ normal) > 0.7:
        return spread
    return "vary both the rod tilt (10-20 deg about two axes) and the crossing position in the scan plane"


def _require_observable(fisher: FloatArray, opts: SolverOptions, extras: _Extras) -> None:
    """Refuse (``DegenerateDataError``) extra parameters the waypoints cannot separate from the pose."""
    scale = 1.0 / np.sqrt(np.clip(np.diag(fisher), 1e-300, None))
    eigenvalues = np.linalg.eigvalsh(fisher * np.outer(scale, scale))
    ratio = float(np.sqrt(max(eigenvalues[0], 0.0) / eigenvalues[-1])) if eigenvalues[-1] > 0 else 0.0
    if ratio >= opts.min_condition_ratio * 10.0:
        return
    std = _crb_std(fisher)
    parts = []
    if extras.axis:
        parts.append(_axis_advice(std[6:8], np.degrees(std[8:10]), opts))
    if extras.offset:
        parts.append(
            "for the range offset, vary the crossings' distance from the scanner (0.3 m or more apart)"
        )
    raise DegenerateDataError(
        f"the {'rod axis' if extras.axis else 'range offset'} cannot be told apart from the scanner pose "
        f"with these waypoints (singular-value ratio {ratio:.1e}): {'; '.join(parts)}"
    )
