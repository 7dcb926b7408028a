"""Rod/plane intersection used to design and check trajectories."""

from __future__ import annotations

import math

import numpy as np

from lasercal_hw.geometry import make_transform, rotvec_to_matrix
from lasercal_hw.models import RodLine
from trajectories.plane_crossing import horizontal_plane, rod_plane_crossings


def tcp(position: list[float], rotvec: list[float]) -> np.ndarray:
    return make_transform(rotvec_to_matrix(rotvec), position)


def test_vertical_rod_crosses_a_horizontal_plane_below_the_tcp() -> None:
    down = tcp([0.5, -0.2, 0.35], [math.pi, 0.0, 0.0])
    crossings = rod_plane_crossings(down, RodLine(), horizontal_plane(0.2))
    np.testing.assert_allclose(crossings.uv_m, [[0.5, -0.2]], atol=1e-12)
    np.testing.assert_allclose(crossings.along_rod_m, [0.15], atol=1e-12)
    assert crossings.within_rod.all()
    np.testing.assert_allclose(crossings.range_m, [math.hypot(0.5, 0.2)])
    np.testing.assert_allclose(crossings.bearing_rad, [math.atan2(-0.2, 0.5)])


def test_tilted_rod_shifts_the_crossing_by_tan_of_the_tilt() -> None:
    tilt = math.radians(20.0)
    # pointing down, then tilted about tool y: the rod end swings along base -x
    rotation = rotvec_to_matrix([math.pi, 0.0, 0.0]) @ rotvec_to_matrix([0.0, tilt, 0.0])
    pose = make_transform(rotation, [0.5, 0.0, 0.35])
    crossings = rod_plane_crossings(pose, RodLine(), horizontal_plane(0.2))
    np.testing.assert_allclose(abs(crossings.uv_m[0, 0] - 0.5), 0.15 * math.tan(tilt), atol=1e-12)
    np.testing.assert_allclose(crossings.along_rod_m, [0.15 / math.cos(tilt)], atol=1e-12)


def test_rod_offset_and_length_decide_within_rod() -> None:
    down = tcp([0.5, -0.2, 0.35], [math.pi, 0.0, 0.0])
    drill = RodLine(origin_m=np.array([0.0, 0.0, 0.15]), length_m=0.1)
    assert rod_plane_crossings(down, drill, horizontal_plane(0.15)).within_rod.all()  # 0.05 along the bit
    assert not rod_plane_crossings(down, drill, horizontal_plane(0.25)).within_rod.any()  # above the bit
    assert not rod_plane_crossings(down, drill, horizontal_plane(0.05)).within_rod.any()  # below its tip


def test_rod_parallel_to_the_plane_has_no_crossing() -> None:
    sideways = tcp([0.5, -0.2, 0.35], [0.0, math.pi / 2, 0.0])  # tool z along base x
    crossings = rod_plane_crossings(sideways, RodLine(), horizontal_plane(0.2))
    assert np.isnan(crossings.along_rod_m).all()
    assert not crossings.within_rod.any()


def test_crossings_are_expressed_in_the_plane_frame() -> None:
    plane = make_transform(rotvec_to_matrix([0.0, 0.0, math.pi / 2]), [0.3, 0.5, 0.2])  # x along base y
    down = tcp([0.3, 1.0, 0.35], [math.pi, 0.0, 0.0])
    crossings = rod_plane_crossings(down, RodLine(), plane)
    np.testing.assert_allclose(crossings.uv_m, [[0.5, 0.0]], atol=1e-12)
