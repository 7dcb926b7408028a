"""The fake cell's world: exact ray casting, noise models, scene files."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.hokuyo import codec
from fakes.scene import Scene, load_scene, parse_scene
from fakes.scip_device import ScipDevice
from fakes.world import DROPOUT_CODE, NO_RETURN_CODE, TOO_NEAR_CODE, World, WorldRangeSource
from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import (
    euler_zyx_to_matrix,
    invert_transform,
    make_transform,
    matrix_to_euler_zyx,
    matrix_to_pose,
)
from lasercal_hw.models import LaserScan
from lasercal_hw.scan.average import AveragedScan, average_scans
from lasercal_hw.scan.extraction import find_rod_centre

IDEAL = 'model = "ideal"\n'
"""The exact-ray model with the [noise] settings: these tests pin its behaviour."""

QUIET = """
[noise]
robot_position_error_m = 0.0
robot_rotation_error_deg = 0.0
"""

# Scanner level at 1 m, looking along base +x; one wall 2 m ahead; nothing else.
WALL_AHEAD = """
walls = [{ name = "front", start_m = [2.0, -3.0], end_m = [2.0, 3.0], z_min_m = 0.0, z_max_m = 2.0 }]
[scanner]
translation_m = [0.0, 0.0, 1.0]
euler_zyx_deg = [0.0, 0.0, 0.0]
[floor]
enabled = false
[column]
enabled = false
"""


def _tcp_for_rod_in_scanner(world: World, point_m, axis) -> np.ndarray:
    """TCP pose whose rod (along TCP z) passes through ``point_m`` along ``axis``, both
    in the scanner frame, with the rod's middle at the point."""
    z = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    start = np.asarray(point_m, dtype=float) - 0.5 * world.rod.length_m * z
    return world.ground_truth_T_base_laser @ make_transform(R, start)


def _rod_beams(world: World, ranges: np.ndarray, clear: np.ndarray) -> np.ndarray:
    return np.flatnonzero(np.abs(ranges - clear) > 1e-9)


def test_default_scene_matches_the_documented_defaults() -> None:
    assert load_scene(None) == Scene()
    world = World.from_scene()
    T = world.ground_truth_T_base_laser
    np.testing.assert_allclose(T[:3, 3], [0.30, 0.50, 0.20])
    np.testing.assert_allclose(np.degrees(matrix_to_euler_zyx(T[:3, :3])), [5.0, 7.0, 3.0], atol=1e-12)
    assert world.angles_rad.size == 1081
    assert world.angles_rad[540] == 0.0
    assert np.degrees(world.angles_rad[-1] - world.angles_rad[0]) == pytest.approx(270.0)
    assert world.rod.radius_m == 0.02 and world.rod.length_m == 0.3


def test_perpendicular_rod_gives_the_circle() -> None:
    world = World(parse_scene(IDEAL + QUIET))
    centre, radius = np.array([0.8, 0.15]), world.rod.radius_m
    T = _tcp_for_rod_in_scanner(world, [*centre, 0.0], [0.0, 0.0, 1.0])
    ranges = world.scan_ranges_m(T)
    clear = world.scan_ranges_m(_tcp_for_rod_in_scanner(world, [0.0, 0.0, 5.0], [0.0, 0.0, 1.0]))
    d = np.stack([np.cos(world.angles_rad), np.sin(world.angles_rad)], -1)
    along = d @ centre
    miss_sq = centre @ centre - along**2
    predicted_hit = miss_sq < radius**2
    beams = _rod_beams(world, ranges, clear)
    np.testing.assert_array_equal(beams, np.flatnonzero(predicted_hit))
    expected = along[beams] - np.sqrt(radius**2 - miss_sq[beams])
    np.testing.assert_allclose(ranges[beams], expected, atol=1e-12)


def test_tilted_rod_gives_the_ellipse() -> None:
    world = World(parse_scene(IDEAL + QUIET))
    tilt = np.radians(35.0)
    axis = np.array([np.sin(tilt) * np.cos(0.7), np.sin(tilt) * np.sin(0.7), np.cos(tilt)])
    centre = np.array([0.6, -0.2, 0.0])
    ranges = world.scan_ranges_m(_tcp_for_rod_in_scanner(world, centre, axis))
    clear = world.scan_ranges_m(_tcp_for_rod_in_scanner(world, [0.0, 0.0, 5.0], [0.0, 0.0, 1.0]))
    beams = _rod_beams(world, ranges, clear)
    assert beams.size > 10
    angles = world.angles_rad[beams]
    points = ranges[beams, None] * np.stack([np.cos(angles), np.sin(angles)], -1)
    major = axis[:2] / np.linalg.norm(axis[:2])
    minor = np.array([-major[1], major[0]])
    rel = points - centre[:2]
    semi_major = world.rod.radius_m / np.cos(tilt)
    on_ellipse = (rel @ major / semi_major) ** 2 + (rel @ minor / world.rod.radius_m) ** 2
    np.testing.assert_allclose(on_ellipse, 1.0, atol=1e-9)


def test_rod_end_caps_limit_a_drill_bit() -> None:
    drill = QUIET + "\n[rod]\nradius_m = 0.005\norigin_m = [0.0, 0.0, 0.12]\nlength_m = 0.10\n"
    world = World(parse_scene(IDEAL + drill))
    clear = world.scan_ranges_m(_tcp_for_rod_in_scanner(world, [0.0, 0.0, 5.0], [0.0, 0.0, 1.0]))
    flange_in_scanner = make_transform(np.eye(3), [0.5, 0.0, -0.17])  # plane crosses the bit
    hit = world.scan_ranges_m(world.ground_truth_T_base_laser @ flange_in_scanner)
    assert 0 < _rod_beams(world, hit, clear).size < 10
    flange_in_scanner = make_transform(np.eye(3), [0.5, 0.0, -0.05])  # plane between flange and bit
    miss = world.scan_ranges_m(world.ground_truth_T_base_laser @ flange_in_scanner)
    assert _rod_beams(world, miss, clear).size == 0


def test_wall_at_a_known_distance() -> None:
    world = World(parse_scene(IDEAL + WALL_AHEAD + QUIET))
    ranges = world.scan_ranges_m(make_transform(np.eye(3), [0.0, 0.0, 5.0]))
    angles = world.angles_rad
    on_wall = np.abs(np.tan(angles)) * 2.0 < 3.0
    on_wall &= np.cos(angles) > 0
    np.testing.assert_allclose(ranges[on_wall], 2.0 / np.cos(angles[on_wall]), rtol=1e-12)
    assert np.all(np.isinf(ranges[~on_wall]))


def test_beyond_dmax_and_nearer_than_dmin_become_error_codes() -> None:
    far = WALL_AHEAD.replace("[scanner]", "[scanner]\nmax_range_m = 1.5")
    world = World(parse_scene(IDEAL + far + QUIET))
    T_away = make_transform(np.eye(3), [0.0, 0.0, 5.0])
    assert np.all(np.isinf(world.scan_ranges_m(T_away)))
    ranges_mm, intensities = world.scan_mm(T_away)
    assert np.all(ranges_mm == NO_RETURN_CODE)
    assert np.all(intensities == 0)
    near = WALL_AHEAD.replace("[2.0, -3.0], end_m = [2.0, 3.0]", "[0.015, -3.0], end_m = [0.015, 3.0]")
    ranges_mm, _ = World(parse_scene(IDEAL + near + QUIET)).scan_mm(T_away)
    assert ranges_mm[540] == TOO_NEAR_CODE


def test_range_noise_and_bias_statistics() -> None:
    noisy = WALL_AHEAD + """
[noise]
range_sigma_m = 0.010
range_sigma_far_m = 0.030
far_from_m = 2.1
bias_offset_m = 0.004
bias_per_m = 0.002
dropout_probability = 0.0
mixed_pixel_probability = 0.0
robot_position_error_m = 0.0
robot_rotation_error_deg = 0.0
"""
    world = World(parse_scene(IDEAL + noisy))
    rng = np.random.default_rng(1)
    T_away = make_transform(np.eye(3), [0.0, 0.0, 5.0])
    scans = np.stack([world.scan_ranges_m(T_away, rng) for _ in range(400)])
    front = slice(540 - 10, 540 + 11)  # ranges 2.0 .. 2.003 m: near sigma
    side = np.abs(world.angles_rad) > np.radians(40)  # ranges > 2.6 m: far sigma
    side &= np.isfinite(scans[0])
    truth = world.scan_ranges_m(T_away)
    error_front = scans[:, front] - truth[front]
    assert np.mean(error_front) == pytest.approx(0.004 + 0.002 * 2.0, abs=0.0005)
    assert np.std(error_front) == pytest.approx(0.010, rel=0.05)
    assert np.std(scans[:, side] - truth[side]) == pytest.approx(0.030, rel=0.05)


def test_dropouts_become_error_codes_at_the_set_rate() -> None:
    world = World(parse_scene(IDEAL + WALL_AHEAD + "[noise]\ndropout_probability = 0.05\n"))
    rng = np.random.default_rng(2)
    T_away = make_transform(np.eye(3), [0.0, 0.0, 5.0])
    codes = np.stack([world.scan_mm(T_away, rng)[0] for _ in range(100)])
    on_wall = np.isfinite(world.scan_ranges_m(T_away))
    fraction = np.mean(codes[:, on_wall] == DROPOUT_CODE)
    assert fraction == pytest.approx(0.05, abs=0.005)


def _edge_values(probability: float) -> np.ndarray:
    scene = WALL_AHEAD + f"""
[noise]
range_sigma_m = 0.0
dropout_probability = 0.0
mixed_pixel_probability = {probability}
robot_position_error_m = 0.0
robot_rotation_error_deg = 0.0
"""
    world = World(parse_scene(IDEAL + scene))
    rng = np.random.default_rng(3)
    between = []
    for offset in np.linspace(0.0, 0.004, 9):  # slide the rod across one beam spacing
        T = _tcp_for_rod_in_scanner(world, [1.0, offset, 0.0], [0.0, 0.0, 1.0])
        ranges = world.scan_ranges_m(T, rng)
        values = ranges[np.isfinite(ranges)]
        between.extend(values[(values > 1.0) & (values < 1.995)].tolist())
    return np.array(between)


def test_mixed_pixels_appear_only_when_enabled() -> None:
    # Rod surface within 0.98..1.0 m, wall at 2 m: a clean beam is < 1.0 m or >= 2.0 m.
    assert _edge_values(0.0).size == 0
    mixed = _edge_values(1.0)
    assert mixed.size >= 4
    assert np.all((mixed > 1.0) & (mixed < 2.0))


def test_robot_error_is_small_repeatable_and_smooth() -> None:
    world = World(parse_scene("[noise]\nrobot_position_error_m = 0.001\nrobot_rotation_error_deg = 0.02\n"))
    rng = np.random.default_rng(4)
    offsets, angles = [], []
    for _ in range(300):
        T = make_transform(euler_zyx_to_matrix(*rng.uniform(-np.pi, np.pi, 3)), rng.uniform(-0.8, 0.8, 3))
        true = world.robot_error.true_pose(T)
        np.testing.assert_array_equal(true, world.robot_error.true_pose(T.copy()))
        offsets.append(true[:3, 3] - T[:3, 3])
        angles.append(np.linalg.norm(matrix_to_pose(true @ invert_transform(T))[3:]))
        nearby = T.copy()
        nearby[:3, 3] += 0.001
        drift = world.robot_error.true_pose(nearby)[:3, 3] - nearby[:3, 3] - offsets[-1]
        assert np.linalg.norm(drift) < 1e-4
    rms = np.sqrt(np.mean(np.square(offsets), axis=0))
    np.testing.assert_allclose(rms, 0.001, rtol=0.35)
    assert np.degrees(np.sqrt(np.mean(np.square(angles)) / 3)) == pytest.approx(0.02, rel=0.35)
    quiet = World(parse_scene(IDEAL + QUIET))
    T = make_transform(np.eye(3), [0.4, 0.1, 0.3])
    np.testing.assert_array_equal(quiet.robot_error.true_pose(T), T)


def test_intensities_are_zero_without_return_and_fall_at_grazing_incidence() -> None:
    world = World(parse_scene(WALL_AHEAD + QUIET))
    ranges_mm, intensities = world.scan_mm(make_transform(np.eye(3), [0.0, 0.0, 5.0]))
    assert np.all(intensities[ranges_mm == NO_RETURN_CODE] == 0)
    assert intensities[540] > intensities[540 + 200] > 0


def _dwell(world: World, T_base_tcp: np.ndarray, rng: np.random.Generator, count: int) -> AveragedScan:
    """What the sequencer does at a waypoint: wire values -> LaserScan -> robust average."""
    scans = []
    for k in range(count):
        mm, intensities = world.scan_mm(T_base_tcp, rng)
        ranges_m = np.where(mm >= 23, mm / 1000.0, np.nan)
        scans.append(LaserScan(k, world.geometry, ranges_m, mm, intensities, 0.025 * k, 0.025 * k))
    return average_scans(scans)


def test_ideal_world_dwell_gives_the_rod_centre_through_extraction() -> None:
    world = World(parse_scene(IDEAL))
    rng = np.random.default_rng(5)
    T_base_laser = world.ground_truth_T_base_laser
    T = T_base_laser @ make_transform(euler_zyx_to_matrix(0.3, 0.2, -0.1), [0.7, 0.1, -0.15])
    scan = _dwell(world, T, rng, 120)
    background = _dwell(world, T_base_laser @ make_transform(np.eye(3), [0.0, 0.0, 3.0]), rng, 120)
    start, axis = world.rod_shape_in_scanner(world.robot_error.true_pose(T))
    true_centre = start[:2] - start[2] / axis[2] * axis[:2]
    result = find_rod_centre(scan, radius_m=0.02, background=background, axis_in_scanner=axis)
    assert np.linalg.norm(result.centre_uv_m - true_centre) < 1.5e-3
    assert result.quality.beams_used >= 8


def test_range_source_gives_one_repeatable_scan_per_time() -> None:
    world = World.from_scene()
    T = world.ground_truth_T_base_laser @ make_transform(np.eye(3), [0.7, 0.0, -0.15])
    pose = matrix_to_pose(T)
    source = WorldRangeSource(world, lambda time_s: pose, seed=6, power_on_s=-3600.0)  # warm
    ranges, intensities = source.ranges_mm(0.0)
    assert ranges.shape == intensities.shape == (1081,)
    assert ranges.dtype == intensities.dtype == np.int64
    again, _ = source.ranges_mm(0.0)
    np.testing.assert_array_equal(again, ranges)
    assert not np.array_equal(source.ranges_mm(0.025)[0], ranges)  # a new scan, new noise
    truth = world.scan_ranges_m(T)
    valid = np.isfinite(truth) & (ranges >= 23)
    assert np.median(np.abs(ranges[valid] / 1000.0 - truth[valid])) < 0.01


def test_range_source_plugs_into_the_fake_scanner() -> None:
    world = World.from_scene()
    pose = matrix_to_pose(world.ground_truth_T_base_laser @ make_transform(np.eye(3), [0.7, 0.0, -0.15]))
    source = WorldRangeSource(world, lambda time_s: pose, seed=6)
    device = ScipDevice(source)
    device.handle(b"BM", 1.0)
    lines = device.handle(b"GE0100020001", 1.0).data[:-2].split(b"\n")
    scan = codec.decode_scan_lines(lines[2:], codec.parse_scan_request(lines[0]))
    ranges, intensities = source.ranges_mm(device.scan_start_s(39))  # the revolution before 1.0 s
    np.testing.assert_array_equal(scan.distances_mm, ranges[100:201])
    assert scan.intensities is not None
    np.testing.assert_array_equal(scan.intensities, intensities[100:201])


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[rod]\nradius_m = -0.02\n", r"rod\.radius_m: Input should be greater than 0"),
        ("[rod]\nradius = 0.02\n", r"rod\.radius: Extra inputs are not permitted"),
        ("[rod]\ndirection = [0.0, 0.0, 0.0]\n", r"rod\.direction: Value error, must not be the zero vector"),
        ("[noise]\ndropout_probability = 1.5\n", r"noise\.dropout_probability: Input should be less than or"),
        ("walls = [{ start_m = [1.0, 1.0], end_m = [1.0, 1.0] }]\n", r"walls\.0: Value error, wall 'wall'"),
        ("[scanner]\ntranslation_m = [0.1, 0.2]\n", r"scanner\.translation_m: List should have at least 3"),
        ("[scanner\n", r"not valid TOML"),
        ("[faults]\nprotective_stop_at_waypoint = -1\n", r"faults\.protective_stop_at_waypoint"),
    ],
)
def test_scene_errors_name_the_field(text: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        parse_scene(text, "my_scene.toml")


def test_scene_file_errors_name_the_file(tmp_path) -> None:
    with pytest.raises(ConfigError, match="cannot read scene file"):
        load_scene(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[rod]\nradius_m = 0\n")
    with pytest.raises(ConfigError, match=r"bad\.toml is invalid: rod\.radius_m"):
        load_scene(bad)
    good = tmp_path / "drill.toml"
    good.write_text("[rod]\nradius_m = 0.005\n[faults]\nprotective_stop_at_waypoint = 4\n")
    scene = load_scene(good)
    assert scene.rod.radius_m == 0.005 and scene.faults.protective_stop_at_waypoint == 4
    assert scene.walls == Scene().walls


def test_no_blend_with_an_empty_background() -> None:
    scene = """
walls = []
[floor]
enabled = false
[column]
enabled = false
[noise]
range_sigma_m = 0.0
dropout_probability = 0.0
mixed_pixel_probability = 1.0
robot_position_error_m = 0.0
robot_rotation_error_deg = 0.0
"""
    world = World(parse_scene(IDEAL + scene))
    rng = np.random.default_rng(7)
    for offset in np.linspace(0.0, 0.004, 9):
        ranges = world.scan_ranges_m(_tcp_for_rod_in_scanner(world, [1.0, offset, 0.0], [0, 0, 1]), rng)
        finite = ranges[np.isfinite(ranges)]
        assert finite.size > 0
        assert np.all(finite < 1.0)  # edge beams keep the rod or return nothing


_QUIET_WORLD = World(parse_scene(IDEAL + QUIET))
_CLEAR = _QUIET_WORLD.scan_ranges_m(_tcp_for_rod_in_scanner(_QUIET_WORLD, [0.0, 0.0, 5.0], [0.0, 0.0, 1.0]))


@settings(max_examples=60, deadline=None)
@given(
    range_m=st.floats(0.3, 1.5),
    bearing_rad=st.floats(-1.9, 1.9),  # clear of the base column behind-right of the scanner
    tilt_rad=st.floats(0.0, 1.1),
    azimuth_rad=st.floats(-np.pi, np.pi),
)
def test_every_rod_hit_lies_on_the_rod_surface(
    range_m: float, bearing_rad: float, tilt_rad: float, azimuth_rad: float
) -> None:
    world = _QUIET_WORLD
    axis = np.array(
        [np.sin(tilt_rad) * np.cos(azimuth_rad), np.sin(tilt_rad) * np.sin(azimuth_rad), np.cos(tilt_rad)]
    )
    centre = np.array([range_m * np.cos(bearing_rad), range_m * np.sin(bearing_rad), 0.0])
    ranges = world.scan_ranges_m(_tcp_for_rod_in_scanner(world, centre, axis))
    beams = _rod_beams(world, ranges, _CLEAR)
    assert beams.size >= 2
    angles = world.angles_rad[beams]
    points = ranges[beams, None] * np.stack([np.cos(angles), np.sin(angles), np.zeros(beams.size)], -1)
    rel = points - centre
    radial = rel - (rel @ axis)[:, None] * axis
    np.testing.assert_allclose(np.linalg.norm(radial, axis=1), world.rod.radius_m, atol=1e-9)
    assert np.all(ranges[beams] < _CLEAR[beams])
