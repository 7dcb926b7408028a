"""Motion model of the fake controller."""

from __future__ import annotations

import numpy as np
import pytest

from fakes.ur_controller.motion import JointPath, LinearPath, Motion, TrapezoidProfile, track_pose
from lasercal_hw.ur_kinematics import forward_kinematics

Q_HOME = np.array([0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0])


@pytest.mark.parametrize(("length", "speed", "accel"), [(1.0, 0.5, 1.0), (0.01, 0.5, 1.0)])
def test_trapezoid_reaches_length_with_bounded_speed(length: float, speed: float, accel: float) -> None:
    profile = TrapezoidProfile(length, speed, accel)
    times = np.linspace(0.0, profile.duration_s, 2001)
    samples = np.array([profile.sample(t) for t in times])
    assert samples[-1, 0] == pytest.approx(length)
    assert np.all(np.diff(samples[:, 0]) >= -1e-12)
    assert samples[:, 1].max() <= speed + 1e-9
    assert np.all(np.abs(np.diff(samples[:, 1]) / np.diff(times)) <= accel * 1.001)


def test_stop_decelerates_along_the_path() -> None:
    motion = Motion(JointPath(np.zeros(6), np.full(6, 1.0)), 1.0, 2.0)
    for _ in range(300):
        q = motion.advance(0.002, np.zeros(6))
    motion.stop(4.0)
    assert motion.stopping and not motion.finished
    while not motion.finished:
        q_stop = motion.advance(0.002, np.zeros(6))
    assert q_stop is not None and q is not None
    assert np.all(q_stop > q) and np.all(q_stop < 1.0)


def test_linear_path_keeps_the_tcp_on_the_straight_line() -> None:
    T_start = forward_kinematics(Q_HOME)
    T_goal = T_start.copy()
    T_goal[:3, 3] += [0.1, -0.05, -0.08]
    q = Q_HOME.copy()
    path = LinearPath(T_start, T_goal, lambda T, qp: track_pose(forward_kinematics, T, qp))
    motion = Motion(path, 0.25, 1.2)
    direction = (T_goal[:3, 3] - T_start[:3, 3]) / np.linalg.norm(T_goal[:3, 3] - T_start[:3, 3])
    while not motion.finished:
        q = motion.advance(0.002, q)
        offset = forward_kinematics(q)[:3, 3] - T_start[:3, 3]
        assert np.linalg.norm(offset - direction * (offset @ direction)) < 1e-7
    assert np.allclose(forward_kinematics(q), T_goal, atol=1e-8)
