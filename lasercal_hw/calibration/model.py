"""Measurement model of the rod calibration, vectorised over waypoints.

For waypoint i the rod axis in the base frame is the line ``o_i + s d_i``.  With the
scanner pose ``T_base_laser = (R, t)`` the line in the scanner frame is ``a_i + s b_i``
(``a = R^T (o - t)``, ``b = R^T d``); it pierces the scan plane z = 0 at
``s = -a_z / b_z`` in the point ``p_i = (x_i, y_i, 0)``, which is compared with the
measured centre (u_i, v_i).  The line parameter is thus eliminated in closed form.

Perturbations (the parameters of the Jacobian and covariance): a translation ``dt`` of
the scanner origin in base coordinates (m) and a small rotation ``e`` about the base
axes (rad), ``R' = exp([e]x) R``.  With ``A_i = [[1, 0, -b_x/b_z], [0, 1, -b_y/b_z]]``:

    d p_i / d dt = -A_i R^T          d p_i / d e = A_i [p_i]x R^T

Noise model: the centre (u, v) has covariance ``C_i`` (from extraction, or isotropic
``sigma_uv``); the robot's reported TCP position has isotropic error ``sigma_robot``,
which moves the crossing point by ``A_i R^T dp``.  The effective covariance of the
residual is ``C_i + sigma_robot^2 A_i A_i^T`` (first order; the robot's orientation
error is not modelled).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from lasercal_hw.geometry import FloatArray, pose_to_matrix, skew
from lasercal_hw.models import RodLine


def rod_lines_in_base(tcp_poses: FloatArray, rod: RodLine) -> tuple[FloatArray, FloatArray]:
    """Origins (N, 3) and unit directions (N, 3) of the rod axis in the base frame."""
    return rod_lines_of_transforms(pose_to_matrix(np.asarray(tcp_poses, dtype=float)), rod)


def rod_lines_of_transforms(transforms: FloatArray, rod: RodLine) -> tuple[FloatArray, FloatArray]:
    """``rod_lines_in_base`` from the TCP poses as 4x4 transforms (N, 4, 4)."""
    rotations = transforms[:, :3, :3]
    origins = rotations @ np.asarray(rod.origin_m, dtype=float) + transforms[:, :3, 3]
    directions = rotations @ rod.unit_direction()
    return origins, directions


def lines_in_scanner(
    rotation: FloatArray, translation_m: FloatArray, origins: FloatArray, directions: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The rod lines in the scanner frame: points a (N, 3) and directions b (N, 3)."""
    return (origins - translation_m) @ rotation, directions @ rotation


def plane_crossing(
    rotation: FloatArray, translation_m: FloatArray, origins: FloatArray, directions: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Crossing points (N, 2) of the rod lines with the scan plane, the slopes
    ``g = (b_x, b_y) / b_z`` (N, 2) that define ``A = [[1, 0, -g_x], [0, 1, -g_y]]``, and the
    line parameters s (N,) of the crossings (measured from the rod origin)."""
    a, b = lines_in_scanner(rotation, translation_m, origins, directions)
    slope = b[:, :2] / b[:, 2:3]
    crossing = a[:, :2] - a[:, 2:3] * slope
    return crossing, slope, -a[:, 2] / b[:, 2]


def residuals_and_jacobian(
    rotation: FloatArray,
    translation_m: FloatArray,
    origins: FloatArray,
    directions: FloatArray,
    centres_uv_m: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Predicted minus measured centre (N, 2), its Jacobian (N, 2, 6) in (dt, e), and the
    slopes (N, 2) of ``A``.

    Written out: ``A R^T`` has rows ``R[:, 0] - g_x R[:, 2]`` and ``R[:, 1] - g_y R[:, 2]``;
    ``A [p]x R^T`` has rows ``g_x y R0 - g_x x R1 + y R2`` and ``g_y y R0 - g_y x R1 - x R2``.
    """
    crossing, slope, _ = plane_crossing(rotation, translation_m, origins, directions)
    x, y = crossing[:, 0], crossing[:, 1]
    gx, gy = slope[:, 0], slope[:, 1]
    r0, r1, r2 = rotation[:, 0], rotation[:, 1], rotation[:, 2]
    outer = np.multiply.outer
    jac = np.empty((len(crossing), 2, 6))
    jac[:, 0, :3] = outer(gx, r2) - r0
    jac[:, 1, :3] = outer(gy, r2) - r1
    jac[:, 0, 3:] = outer(gx * y, r0) - outer(gx * x, r1) + outer(y, r2)
    jac[:, 1, 3:] = outer(gy * y, r0) - outer(gy * x, r1) - outer(x, r2)
    return crossing - centres_uv_m, jac, slope


def effective_covariance(covariance_uv_m2: FloatArray, slope: FloatArray, robot_sigma_m: float) -> FloatArray:
    """Residual covariance per waypoint (N, 2, 2): centre noise plus robot position noise
    ``sigma^2 A A^T = sigma^2 (I + g g^T)``."""
    spread = np.eye(2) + slope[:, :, None] * slope[:, None, :]
    return covariance_uv_m2 + robot_sigma_m**2 * spread


def whitening(covariance: FloatArray) -> FloatArray:
    """Upper-triangular ``U`` (N, 2, 2) with ``U^T U = inv(covariance)``."""
    c00, c01, c11 = covariance[:, 0, 0], covariance[:, 0, 1], covariance[:, 1, 1]
    det = c00 * c11 - c01 * c01
    s00, s01, s11 = c11 / det, -c01 / det, c00 / det
    u00 = np.sqrt(s00)
    u01 = s01 / u00
    u11 = np.sqrt(np.maximum(s11 - u01 * u01, 0.0))
    w = np.zeros_like(covariance)
    w[:, 0, 0], w[:, 0, 1], w[:, 1, 1] = u00, u01, u11
    return w


def whiten_residual(white: FloatArray, residual: FloatArray) -> FloatArray:
    """Whitened residuals (N, 2) for upper-triangular ``white``."""
    r = np.empty_like(residual)
    r[:, 0] = white[:, 0, 0] * residual[:, 0] + white[:, 0, 1] * residual[:, 1]
    r[:, 1] = white[:, 1, 1] * residual[:, 1]
    return r


def whiten(white: FloatArray, residual: FloatArray, jac: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Whitened residual (2N,) and Jacobian (2N, k) for upper-triangular ``white``."""
    u00, u01, u11 = white[:, 0, 0, None], white[:, 0, 1, None], white[:, 1, 1, None]
    j = np.empty_like(jac)
    j[:, 0] = u00 * jac[:, 0] + u01 * jac[:, 1]
    j[:, 1] = u11 * jac[:, 1]
    return whiten_residual(white, residual).reshape(-1), j.reshape(-1, jac.shape[-1])


def left_jacobian_so3(rotvec: FloatArray) -> FloatArray:
    """``J_l(phi)`` with ``exp(phi + d) = exp(J_l(phi) d) exp(phi)`` to first order."""
    angle = float(np.linalg.norm(rotvec))
    k = skew(rotvec)
    if angle < 1e-8:
        return np.eye(3) + 0.5 * k
    return np.eye(3) + (1.0 - np.cos(angle)) / angle**2 * k + (angle - np.sin(angle)) / angle**3 * (k @ k)


def fisher_information(
    rotation: FloatArray,
    translation_m: FloatArray,
    origins: FloatArray,
    directions: FloatArray,
    covariance_uv_m2: FloatArray,
    robot_sigma_m: float,
) -> FloatArray:
    """Fisher information (6, 6) of (dt, e) for these rod lines and noise model; its
    inverse is the Cramér-Rao bound of any unbiased estimator."""
    zeros = np.zeros((len(origins), 2))
    _, jac, slope = residuals_and_jacobian(rotation, translation_m, origins, directions, zeros)
    white = whitening(effective_covariance(covariance_uv_m2, slope, robot_sigma_m))
    _, j = whiten(white, zeros, jac)
    return j.T @ j


def euler_zyx_axes(yaw_rad: float, pitch_rad: float) -> FloatArray:
    """Columns: the base-frame axes of the three ZYX rotations, so that a change
    ``(d yaw, d pitch, d roll)`` is the small base rotation ``E @ (d yaw, d pitch, d roll)``
    (``E = [z, Rz(yaw) y, Rz(yaw) Ry(pitch) x]``)."""
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    return np.array([[0.0, -sy, cy * cp], [0.0, cy, sy * cp], [1.0, 0.0, -sp]])


# -- extra parameters: the rod axis in the TCP frame and the scanner's range offset --------
#
# The rod line is moved across itself by ``a = (a1, a2)`` (metres) and tilted by
# ``b = (b1, b2)`` (radians, small) along two unit vectors ``e1, e2`` perpendicular to its
# direction ``d`` (``axis_basis``): ``o' = o + a1 e1 + a2 e2``, ``d' = unit(d + b1 e1 + b2 e2)``.
# Moving the line's base-frame origin by ``do`` moves the crossing by ``-J_t do`` (``J_t`` the
# Jacobian in the scanner translation), turning its direction by ``dd`` moves it by
# ``-s J_t dd`` (``s`` the crossing's line parameter). A range error ``e(|p|)`` (measured minus
# true range) moves a centre seen at ``p`` to ``p + e(|p|) p/|p|``. The error is a curve over
# distance (``range_error_m``): a polynomial in ``x = ln(d / RANGE_CURVE_REFERENCE_M)``, whose
# first term is the offset (the error at the reference distance); a range offset alone is the
# curve with one term. Log range because a pulsed scanner's range walk follows the echo's
# intensity, which falls as a power of range (so the walk is linear in ln d), and its unit curve
# is smooth over decades of range (0.1-30 m), not over metres: four terms follow a
# UTM-30LX-EW's curve over 0.3-1.2 m to about 1 mm where powers of (d - ref) need five
# (docs/solver.md). Calibrations solved before kept powers of ``d - ref`` (basis ``distance``).

RANGE_CURVE_REFERENCE_M = 1.0
"""Distance about which the range error's terms are taken: the offset is the error there."""
RangeCurveBasis = Literal["log_distance", "distance"]
"""``log_distance``: powers of ln(d / reference), the solver's; ``distance``: powers of
``d - reference`` (metres), the basis of calibrations solved before (read, never written)."""
RANGE_CURVE_BASIS: RangeCurveBasis = "log_distance"
"""The basis the solver estimates the range error curve in."""


def range_curve_variable(
    distance_m: FloatArray, basis: RangeCurveBasis = RANGE_CURVE_BASIS
) -> tuple[FloatArray, FloatArray]:
    """The curve's variable x at the distances and its derivative dx/dd (1/m)."""
    distance = np.asarray(distance_m, dtype=float)
    if basis == "distance":
        return distance - RANGE_CURVE_REFERENCE_M, np.ones_like(distance)
    return np.log(distance / RANGE_CURVE_REFERENCE_M), 1.0 / distance


def range_error_basis(
    distance_m: FloatArray, terms: int, basis: RangeCurveBasis = RANGE_CURVE_BASIS
) -> FloatArray:
    """The curve's basis functions (N, terms) at the distances."""
    x, _ = range_curve_variable(distance_m, basis)
    return np.stack([x**k for k in range(terms)], axis=-1)


def range_error_m(
    curve: FloatArray, distance_m: FloatArray, basis: RangeCurveBasis = RANGE_CURVE_BASIS
) -> tuple[FloatArray, FloatArray]:
    """The range error (measured minus true, m) of a curve's coefficients at the distances,
    and its slope over distance."""
    coefficients = np.atleast_1d(np.asarray(curve, dtype=float))
    x, dx_dd = range_curve_variable(distance_m, basis)
    error = np.zeros_like(x)
    slope = np.zeros_like(x)
    for k, c in enumerate(coefficients):
        error = error + c * x**k
        if k:
            slope = slope + k * c * x ** (k - 1)
    return error, slope * dx_dd


def axis_basis(direction: FloatArray) -> FloatArray:
    """Two unit vectors (3, 2) perpendicular to ``direction``: the TCP x axis made
    perpendicular to it (y when it is along x), and their cross product."""
    d = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    x = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = x - (x @ d) * d
    e1 /= np.linalg.norm(e1)
    return np.column_stack([e1, np.cross(d, e1)])


def moved_rod(rod: RodLine, axis_step: FloatArray) -> RodLine:
    """The rod moved across its axis by ``axis_step[:2]`` (m) and tilted by ``axis_step[2:]``
    (rad) along ``axis_basis`` of its direction."""
    basis = axis_basis(rod.direction)
    direction = rod.unit_direction() + basis @ np.asarray(axis_step[2:], dtype=float)
    return RodLine(
        origin_m=np.asarray(rod.origin_m, dtype=float) + basis @ np.asarray(axis_step[:2], dtype=float),
        direction=direction / np.linalg.norm(direction),
        radius_m=rod.radius_m,
        length_m=rod.length_m,
    )


def extended_residuals_and_jacobian(
    rotation: FloatArray,
    translation_m: FloatArray,
    tcp_transforms: FloatArray,
    rod: RodLine,
    centres_uv_m: FloatArray,
    range_offset_m: float | FloatArray,
    *,
    with_axis: bool,
    with_offset: bool | int,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Predicted minus measured centre (N, 2), the Jacobian (N, 2, 6 [+4] [+k]) in
    (dt, e[, a1, a2, b1, b2][, c0 .. c(k-1)]) at ``axis_step = 0``, and the slopes (N, 2).

    ``range_offset_m``: the range error curve's coefficients (a number: an offset alone);
    ``with_offset``: how many of its terms are estimated (True: the offset)."""
    rotations = tcp_transforms[:, :3, :3]
    origins = rotations @ np.asarray(rod.origin_m, dtype=float) + tcp_transforms[:, :3, 3]
    directions = rotations @ rod.unit_direction()
    residual, jac, slope = residuals_and_jacobian(rotation, translation_m, origins, directions, centres_uv_m)
    blocks = [jac]
    if with_axis:
        _, _, line_s = plane_crossing(rotation, translation_m, origins, directions)
        moves = rotations @ axis_basis(rod.direction)  # (N, 3, 2): e1, e2 in the base frame
        along_origin = -jac[:, :, :3] @ moves
        # d' = unit(d + B b): at b = 0 the direction turns by B b (perpendicular to d already).
        blocks += [along_origin, line_s[:, None, None] * along_origin]
    full = np.concatenate(blocks, axis=2)
    crossing = residual + centres_uv_m
    curve = np.atleast_1d(np.asarray(range_offset_m, dtype=float))
    terms = int(with_offset)
    if curve.any() or terms:
        move, stretch = range_error_effect(crossing, curve)
        full = stretch @ full
        residual = residual + move
        if terms:
            distance = np.linalg.norm(crossing, axis=1)
            unit = crossing / distance[:, None]
            basis = range_error_basis(distance, terms)
            full = np.concatenate([full, unit[:, :, None] * basis[:, None, :]], axis=2)
    return residual, full, slope


def range_error_effect(
    crossing_uv_m: FloatArray, curve: FloatArray, basis: RangeCurveBasis = RANGE_CURVE_BASIS
) -> tuple[FloatArray, FloatArray]:
    """What a range error curve does to crossings (N, 2): the move (N, 2) along each bearing
    by the error at its distance (where the scanner reads the crossing, less the crossing),
    and the stretch (N, 2, 2) its Jacobian takes (d read / d crossing). The solver's
    prediction and the verify's drift test both read the crossings through it."""
    distance = np.linalg.norm(crossing_uv_m, axis=1)
    unit = crossing_uv_m / distance[:, None]
    error, error_slope = range_error_m(curve, distance, basis)
    radial = unit[:, :, None] * unit[:, None, :]
    stretch = (
        np.eye(2)
        + error[:, None, None] * (np.eye(2) - radial) / distance[:, None, None]
        + error_slope[:, None, None] * radial
    )
    return error[:, None] * unit, stretch


def extended_fisher_information(
    rotation: FloatArray,
    translation_m: FloatArray,
    tcp_transforms: FloatArray,
    rod: RodLine,
    covariance_uv_m2: FloatArray,
    robot_sigma_m: float,
    range_offset_m: float | FloatArray = 0.0,
    *,
    with_axis: bool,
    with_offset: bool | int = False,
) -> FloatArray:
    """Fisher information (6 [+4] [+k] square) of (dt, e[, a1, a2, b1, b2][, c0 ..]) for the rod
    held at ``tcp_transforms`` (N, 4, 4) and the noise model of ``fisher_information``."""
    zeros = np.zeros((len(tcp_transforms), 2))
    _, jac, slope = extended_residuals_and_jacobian(
        rotation,
        translation_m,
        tcp_transforms,
        rod,
        zeros,
        range_offset_m,
        with_axis=with_axis,
        with_offset=with_offset,
    )
    white = whitening(effective_covariance(covariance_uv_m2, slope, robot_sigma_m))
    _, j = whiten(white, zeros, jac)
    return j.T @ j
