"""Property test: any scanner pose is recovered exactly from noise-free, well-spread rods."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from lasercal_hw.calibration.solver import solve
from lasercal_hw.geometry import make_transform, matrix_to_pose, rotvec_to_matrix
from lasercal_hw.models import Observation, RodLine


def _rods_through_plane(truth: np.ndarray, rng: np.random.Generator, count: int) -> list[Observation]:
    """Rods crossing the truth's scan plane at random points, 30-80 deg from the plane."""
    rotation, translation = truth[:3, :3], truth[:3, 3]
    observations = []
    for index in range(count):
        uv = rng.uniform(-1.5, 1.5, 2)
        elevation = np.radians(rng.uniform(30.0, 80.0)) * rng.choice([-1.0, 1.0])
        azimuth = rng.uniform(-np.pi, np.pi)
        flat = np.cos(elevation)
        local = np.array([flat * np.cos(azimuth), flat * np.sin(azimuth), np.sin(elevation)])
        z_axis = rotation @ local
        helper = np.array([1.0, 0.0, 0.0]) if abs(z_axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x_axis = np.cross(helper, z_axis)
        x_axis /= np.linalg.norm(x_axis)
        tcp = make_transform(np.column_stack([x_axis, np.cross(z_axis, x_axis), z_axis]), np.zeros(3))
        crossing = rotation @ np.array([*uv, 0.0]) + translation
        tcp[:3, 3] = crossing - rng.uniform(0.05, 0.5) * z_axis
        observations.append(Observation(index=index, tcp_pose=matrix_to_pose(tcp), centre_uv_m=uv))
    return observations


@settings(max_examples=40, deadline=None)
@given(
    rotvec=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
    translation=st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3),
    seed=st.integers(0, 2**32 - 1),
    count=st.integers(6, 30),
)
def test_any_pose_is_recovered_from_noise_free_rods(
    rotvec: list[float], translation: list[float], seed: int, count: int
) -> None:
    truth = make_transform(rotvec_to_matrix(np.array(rotvec)), np.array(translation))
    observations = _rods_through_plane(truth, np.random.default_rng(seed), count)
    np.testing.assert_allclose(solve(observations, RodLine()).matrix(), truth, atol=1e-7)
