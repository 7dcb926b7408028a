"""Motion model of the fake controller: a path parameterised by arc length and a speed
profile along it.

* moveJ: straight line in joint space; the arc length is the largest joint delta (rad),
  so every joint starts and stops together.
* moveL: straight line of the TCP; the arc length is the Cartesian distance (m), the
  orientation is slerped along the same fraction (a pure rotation uses the angle in rad
  as arc length). The joints follow the path through inverse kinematics near the
  previous joint vector.
* Stops: the current profile is replaced by a constant deceleration along the same path.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from lasercal_hw.geometry import make_transform, matrix_to_rotvec, rotvec_to_matrix
from lasercal_hw.models import FloatArray

IkSolver = Callable[[FloatArray, FloatArray], FloatArray | None]
"""``(T_base_tcp 4x4, q_near) -> q`` or None when unreachable."""

_MIN_LENGTH = 1e-9
_PURE_ROTATION_M = 1e-6


class TrapezoidProfile:
    """Arc length ``s(t)`` from 0 to ``length`` with peak speed and acceleration
    (triangular when the peak speed is never reached)."""

    def __init__(self, length: float, speed: float, accel: float) -> None:
        if speed <= 0.0 or accel <= 0.0:
            raise ValueError(f"speed and acceleration must be positive, got {speed}, {accel}")
        self.length = max(length, 0.0)
        self.accel = accel
        ramp_s = speed / accel
        if accel * ramp_s * ramp_s >= self.length:  # triangular
            ramp_s = math.sqrt(self.length / accel)
            speed = accel * ramp_s
        self.peak_speed = speed
        self.ramp_s = ramp_s
        self.cruise_s = (self.length - accel * ramp_s * ramp_s) / speed if speed > 0.0 else 0.0
        self.duration_s = 2.0 * ramp_s + self.cruise_s

    def sample(self, t: float) -> tuple[float, float]:
        """``(s, ds/dt)`` at time ``t`` after the start."""
        a, v, ramp = self.accel, self.peak_speed, self.ramp_s
        if t <= 0.0:
            return 0.0, 0.0
        if t < ramp:
            return 0.5 * a * t * t, a * t
        if t < ramp + self.cruise_s:
            return 0.5 * a * ramp * ramp + v * (t - ramp), v
        if t < self.duration_s:
            left = self.duration_s - t
            return self.length - 0.5 * a * left * left, a * left
        return self.length, 0.0


class StopProfile:
    """Constant deceleration from arc length ``start`` and speed ``speed`` to rest."""

    def __init__(self, start: float, speed: float, decel: float) -> None:
        self.start = start
        self.speed = max(speed, 0.0)
        self.decel = decel
        self.duration_s = self.speed / decel

    def sample(self, t: float) -> tuple[float, float]:
        """``(s, ds/dt)`` at time ``t`` after the stop began."""
        t = min(max(t, 0.0), self.duration_s)
        return self.start + self.speed * t - 0.5 * self.decel * t * t, self.speed - self.decel * t


class JointPath:
    """Straight line in joint space from ``q_start`` to ``q_target``."""

    def __init__(self, q_start: FloatArray, q_target: FloatArray) -> None:
        self.q_start = np.asarray(q_start, dtype=float)
        self.delta = np.asarray(q_target, dtype=float) - self.q_start
        self.length = float(np.max(np.abs(self.delta)))

    def joints_at(self, s: float, q_previous: FloatArray) -> FloatArray | None:
        """Joint vector at arc length ``s`` (never None: joint paths cannot fail)."""
        fraction = 1.0 if self.length < _MIN_LENGTH else s / self.length
        return self.q_start + fraction * self.delta


class LinearPath:
    """Straight TCP line with slerped orientation, joints by inverse kinematics."""

    def __init__(self, T_start: FloatArray, T_target: FloatArray, solve: IkSolver) -> None:
        self.T_start = np.asarray(T_start, dtype=float)
        self.translation_m = T_target[:3, 3] - self.T_start[:3, 3]
        self.rotvec_rel = matrix_to_rotvec(self.T_start[:3, :3].T @ T_target[:3, :3])
        distance_m = float(np.linalg.norm(self.translation_m))
        angle_rad = float(np.linalg.norm(self.rotvec_rel))
        self.length = distance_m if distance_m > _PURE_ROTATION_M else angle_rad
        self._solve = solve

    def pose_at(self, s: float) -> FloatArray:
        """TCP transform at arc length ``s``."""
        fraction = 1.0 if self.length < _MIN_LENGTH else s / self.length
        rotation = self.T_start[:3, :3] @ rotvec_to_matrix(fraction * self.rotvec_rel)
        return make_transform(rotation, self.T_start[:3, 3] + fraction * self.translation_m)

    def joints_at(self, s: float, q_previous: FloatArray) -> FloatArray | None:
        """Joint vector at arc length ``s`` nearest to ``q_previous``; None if unreachable."""
        return self._solve(self.pose_at(s), q_previous)


class Motion:
    """One move in progress: a path plus the profile that drives it."""

    def __init__(self, path: JointPath | LinearPath, speed: float, accel: float) -> None:
        self.path = path
        self.profile: TrapezoidProfile | StopProfile = TrapezoidProfile(path.length, speed, accel)
        self.elapsed_s = 0.0
        self.stopping = False

    @property
    def finished(self) -> bool:
        """True once the profile has run out."""
        return self.elapsed_s >= self.profile.duration_s

    def advance(self, dt_s: float, q_previous: FloatArray) -> FloatArray | None:
        """Step the motion by ``dt_s``; the joint vector there, or None if unreachable."""
        self.elapsed_s += dt_s
        s, _ = self.profile.sample(self.elapsed_s)
        return self.path.joints_at(s, q_previous)

    def stop(self, decel: float) -> None:
        """Replace the profile by a deceleration to rest along the same path."""
        s, speed = self.profile.sample(self.elapsed_s)
        self.profile = StopProfile(s, speed, decel)
        self.elapsed_s = 0.0
        self.stopping = True


ForwardKinematics = Callable[[FloatArray], FloatArray]
"""``q (..., 6) -> T_base_tcp (..., 4, 4)``, vectorised over leading dimensions."""

_JACOBIAN_STEP_RAD = 1e-7
_TRACK_TOLERANCE = 1e-9
_TRACK_ITERATIONS = 3


def _pose_error(T_target: FloatArray, T_actual: FloatArray) -> FloatArray:
    """6-vector (translation, small-angle rotation in the base frame) from actual to target.

    The rotation part is the vee of the skew part of ``R_target R_actual^T``, exact to
    first order; tracking only ever sees errors of one controller cycle.
    """
    r = T_target[..., :3, :3] @ np.swapaxes(T_actual[..., :3, :3], -1, -2)
    rotation = 0.5 * np.stack(
        [r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], axis=-1
    )
    return np.concatenate([T_target[..., :3, 3] - T_actual[..., :3, 3], rotation], axis=-1)


def track_pose(fk: ForwardKinematics, T_target: FloatArray, q_previous: FloatArray) -> FloatArray | None:
    """Joint vector reaching ``T_target`` by Newton steps from ``q_previous``.

    Meant for following a path in small increments (one controller cycle): each step uses
    a finite-difference Jacobian from one vectorised forward-kinematics call. Returns None
    when the steps do not converge (singularity, out of reach); the caller then falls back
    to a closed-form solution or gives up.
    """
    q = np.asarray(q_previous, dtype=float).copy()
    probes = q + np.vstack([np.zeros(6), _JACOBIAN_STEP_RAD * np.eye(6)])
    for _ in range(_TRACK_ITERATIONS):
        transforms = fk(probes)
        error = _pose_error(T_target, transforms[0])
        if float(np.max(np.abs(error))) < _TRACK_TOLERANCE:
            return q
        jacobian = (_pose_error(transforms[1:], transforms[0]).T) / _JACOBIAN_STEP_RAD
        step, *_ = np.linalg.lstsq(jacobian, error, rcond=1e-6)
        q = q + step
        probes = q + np.vstack([np.zeros(6), _JACOBIAN_STEP_RAD * np.eye(6)])
    final_error = _pose_error(T_target, fk(q))
    return q if float(np.max(np.abs(final_error))) < 1e-7 else None
