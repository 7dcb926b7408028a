"""The physical UTM-30LX-EW model: footprint, echoes, intensity, noise, bias, drift, drill."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fakes.scanner_model.dwell import simulate_dwell
from fakes.scanner_model.echo import detect_echo
from fakes.scanner_model.range_error import range_bias_m, range_sigma_m
from fakes.scene import MODEL_ENV, PhysicsSettings, Scene, load_scene, parse_scene, with_model_override
from fakes.shapes import drill_section
from fakes.world import World
from lasercal_hw.config import load_job
from lasercal_hw.errors import ConfigError
from lasercal_hw.scan.average import average_scans

PHYSICS = PhysicsSettings()


def _beam_towards(dwell, offset: int = 0) -> int:
    angles = dwell.world.angles_rad
    u, v = dwell.centre_uv_m
    return int(np.argmin(np.abs(angles - np.arctan2(v, u)))) + offset


def test_physical_is_the_default_and_ideal_stays_selectable() -> None:
    assert Scene().model == "physical" == load_scene(None).model
    assert World(Scene()).physical is not None
    assert World(parse_scene('model = "ideal"\n')).physical is None


def test_a_dwell_is_repeatable_and_carries_intensities() -> None:
    one = simulate_dwell((0.8, 0.1), 0.02, scan_count=3, seed=4)
    two = simulate_dwell((0.8, 0.1), 0.02, scan_count=3, seed=4)
    for a, b in zip(one.scans, two.scans, strict=True):
        np.testing.assert_array_equal(a.raw_ranges_mm, b.raw_ranges_mm)
        assert a.intensities is not None and b.intensities is not None
        np.testing.assert_array_equal(a.intensities, b.intensities)
    np.testing.assert_allclose(one.centre_uv_m, [0.8, 0.1])
    centre_beam = _beam_towards(one)
    assert abs(one.scans[0].ranges_m[centre_beam] - (np.hypot(0.8, 0.1) - 0.02)) < 0.03


def test_retro_tape_is_brighter_than_paint_and_dark_is_dimmer() -> None:
    levels = {}
    for material in ("retro_tape", "painted", "dark"):
        dwell = simulate_dwell((1.0, 0.0), 0.045, material=material, scan_count=5, background_m=None)
        levels[material] = np.mean([s.intensities[_beam_towards(dwell)] for s in dwell.scans])
    assert levels["retro_tape"] > 3 * levels["painted"] > 3 * levels["dark"] > 0


def test_a_retro_rod_before_a_near_wall_gives_steady_ramps() -> None:
    dwell = simulate_dwell((0.8, 0.1), 0.0225, material="retro_tape", background_m=0.5, scan_count=40)
    scan = average_scans(dwell.scans)
    rod_m, wall_m = np.hypot(0.8, 0.1) - 0.0225, np.hypot(0.8, 0.1) + 0.5
    between = (scan.ranges_m > rod_m + 0.025) & (scan.ranges_m < wall_m - 0.05)
    steady = between & (scan.reading_std_m < 0.015)
    assert np.count_nonzero(steady) >= 4  # mixed pixels that averaging does not remove


def test_noise_grows_with_range_and_falls_with_intensity() -> None:
    bright, dim = range_sigma_m(np.array([30000.0, 1000.0]), PHYSICS)
    assert 0.0015 < bright < dim < 0.010
    near = simulate_dwell((1.0, 0.0), 0.02, background_m=0.2, scan_count=30, material="matte")
    far = simulate_dwell((4.0, 0.0), 0.02, background_m=0.2, scan_count=30, material="matte")
    spread = [average_scans(d.scans).reading_std_m[_beam_towards(d, 40)] for d in (near, far)]
    assert spread[0] < spread[1] < 0.010


def test_bias_stays_within_the_data_sheet_and_grows_at_the_near_end() -> None:
    ranges = np.linspace(0.05, 30.0, 500)
    for intensity in (200.0, 4000.0, 60000.0):
        bias = range_bias_m(ranges, np.full_like(ranges, intensity), PHYSICS)
        assert np.all(np.abs(bias) <= 0.030 + 1e-12)
    at = range_bias_m(np.array([0.105, 1.0]), np.full(2, PHYSICS.reference_intensity), PHYSICS)
    assert at[0] > 0.012 and at[0] - at[1] > 0.005


def test_warm_up_drift_fades_after_power_on() -> None:
    cold_start = PHYSICS.model_copy(update={"warm_at_start": False})

    def front(elapsed_s: float | None, physics: PhysicsSettings = cold_start) -> float:
        dwell = simulate_dwell(
            (1.0, 0.0), 0.02, background_m=0.5, scan_count=20, physics=physics, elapsed_s=elapsed_s
        )
        return float(average_scans(dwell.scans).ranges_m[_beam_towards(dwell, 30)])

    cold, warm = front(0.0), front(None)
    assert cold - warm == pytest.approx(PHYSICS.warmup_drift_m, abs=0.002)
    assert abs(front(10 * PHYSICS.warmup_time_constant_s) - warm) < 0.002
    assert front(0.0, PHYSICS) == pytest.approx(warm, abs=1e-9)  # the fake cell's default: warm


def test_drill_section_has_two_flutes_and_the_web() -> None:
    section = drill_section(0.16)
    radius = np.linalg.norm(section, axis=1)
    assert radius.max() == pytest.approx(1.0)
    assert radius.min() == pytest.approx(0.16, abs=0.01)  # half the web over the radius
    lands = radius > 0.999
    assert 0.3 < lands.mean() < 0.6  # two lands and two flutes share the circumference
    np.testing.assert_allclose(section, -section[np.r_[64:128, 0:64]], atol=1e-12)  # point-symmetric


def test_a_twist_drill_turned_by_the_spindle_changes_its_scan() -> None:
    def noise_free(shape: str, spindle_deg: float) -> np.ndarray:
        dwell = simulate_dwell((0.3, 0.0), 0.005, shape=shape, material="steel_drill",
                               spindle_deg=spindle_deg, background_m=0.3, scan_count=0)
        beam = _beam_towards(dwell)
        return dwell.world.scan_ranges_m(dwell.T_base_tcp)[beam - 3: beam + 4]

    np.testing.assert_allclose(noise_free("cylinder", 0.0), noise_free("cylinder", 90.0), atol=1e-9)
    turned = np.abs(noise_free("twist_drill", 0.0) - noise_free("twist_drill", 90.0))
    assert turned.max() > 0.001  # flutes or lands face the scanner


def test_a_bit_turned_in_its_chuck_scans_as_the_tool_turned_about_the_bit() -> None:
    def ranges(spindle_deg: float, chuck_turn_deg: float) -> np.ndarray:
        dwell = simulate_dwell((0.3, 0.0), 0.005, shape="twist_drill", material="steel_drill",
                               spindle_deg=spindle_deg, background_m=0.3, scan_count=0)
        rod = dwell.world.scene.rod.model_copy(update={"chuck_turn_deg": chuck_turn_deg})
        world = World(dwell.world.scene.model_copy(update={"rod": rod}))
        beam = _beam_towards(dwell)
        return world.scan_ranges_m(dwell.T_base_tcp)[beam - 3: beam + 4]

    np.testing.assert_allclose(ranges(0.0, 40.0), ranges(40.0, 0.0), atol=1e-9)
    np.testing.assert_allclose(ranges(0.0, 220.0), ranges(40.0, 0.0), atol=1e-9)  # two flutes: 180 deg
    assert np.abs(ranges(0.0, -40.0) - ranges(40.0, 0.0)).max() > 0.0005  # the turn has a sense


def test_the_fake_cells_model_can_be_overridden_by_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(MODEL_ENV, "physical")
    assert with_model_override(parse_scene('model = "ideal"\n')).model == "physical"
    monkeypatch.setenv(MODEL_ENV, "")
    assert with_model_override(parse_scene('model = "ideal"\n')).model == "ideal"
    monkeypatch.setenv(MODEL_ENV, "perfect")
    with pytest.raises(ConfigError, match="LASERCAL_FAKE_SCANNER_MODEL='perfect' is not a scanner model"):
        with_model_override(Scene())


def test_the_packaged_drill_scene_holds_the_drill_jobs_bit() -> None:
    root = Path(__file__).resolve().parents[2]
    scene = load_scene(root / "fakes" / "scenes" / "drill.toml")
    job_rod = load_job(root / "examples" / "drill.toml").rod
    assert scene.rod.shape == "twist_drill" and scene.rod.chuck_radius_m > 0.0
    np.testing.assert_allclose(scene.rod.origin_m, job_rod.origin_m)
    np.testing.assert_allclose(scene.rod.direction, job_rod.direction)
    assert scene.rod.radius_m == job_rod.radius_m


def test_a_post_elsewhere_is_clutter_the_size_of_the_rod() -> None:
    dwell = simulate_dwell((0.8, 0.1), 0.02, posts=[(0.9, -0.4, 0.02)], scan_count=0)
    ranges = dwell.world.scan_ranges_m(dwell.T_base_tcp)
    towards_post = int(np.argmin(np.abs(dwell.world.angles_rad - np.arctan2(-0.4, 0.9))))
    assert abs(ranges[towards_post] - (np.hypot(0.9, -0.4) - 0.02)) < 0.03
    with pytest.raises(ConfigError, match=r"posts\.0: Value error, post .p.: z_max_m must be above z_min_m"):
        parse_scene('posts = [{ name = "p", centre_m = [1.0, 0.0], z_min_m = 1.0, z_max_m = 0.5 }]\n')


def test_echoes_merge_when_close_and_compete_when_far() -> None:
    fwhm = PHYSICS.pulse_fwhm_m
    # Two surfaces 0.2 m apart, the nearer with a third of the power: one lobe between them.
    merged = detect_echo(np.array([[1.0, 1.2]]), np.array([[1.0, 2.0]]), fwhm, 0.1)
    assert 1.0 < merged.range_m[0] < 1.2 and merged.rival[0] == 0.0
    # Three metres apart: two lobes; the strongest is reported, the other is its rival.
    far_t, far_power = np.array([[1.0, 4.0]]), np.array([[1.0, 2.0]])
    strongest = detect_echo(far_t, far_power, fwhm, 0.1)
    assert strongest.range_m[0] == pytest.approx(4.0, abs=1e-3)
    assert strongest.rival[0] == pytest.approx(1.0, rel=1e-3)
    first = detect_echo(far_t, far_power, fwhm, 0.1, "first")
    assert first.range_m[0] == pytest.approx(1.0, abs=1e-3)
    # Below the threshold nothing is reported.
    assert np.isinf(detect_echo(far_t, far_power * 0.01, fwhm, 0.1).range_m[0])
