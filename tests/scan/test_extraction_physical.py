"""The physical scanner model's hard cases (issue 18), each a short dwell from
``fakes/scanner_model``: a found rod whose reported covariance covers its error, or a clear
skip; never a silent wrong centre.  The error is taken after the model's range error at the
rod (``front_range_error_m``, along the bearing), as the solver's range-error curve takes it;
what it leaves across the rod's beams must be in the covariance."""

from __future__ import annotations

import numpy as np
import pytest

from fakes.scanner_model.dwell import simulate_dwell, step_behind_edge
from lasercal_hw.scan.average import average_scans
from lasercal_hw.scan.extraction import ExtractionSettings, RodCentre, RodNotFoundError, find_rod_centre
from tests.physical_truth import front_range_error_m

Z_AXIS = np.array([0.0, 0.0, 1.0])
CHI2_2DOF_999 = 13.8  # 99.9 % of an honest covariance's squared Mahalanobis distances
THREE_STD_M2 = 9.0  # issue 18: no centre more than 3 reported std from the truth without a warning


def _extract(
    range_m: float, bearing_deg: float, radius_m: float, material: str, background_m: float | None, **kwargs
) -> tuple[RodCentre | RodNotFoundError, np.ndarray]:
    """The rod's centre from a 10-scan dwell with a 10-scan background, or the refusal, and
    where the scanner sees the rod's centre (the truth moved by the model's range error)."""
    bearing = np.radians(bearing_deg)
    centre = range_m * np.array([np.cos(bearing), np.sin(bearing)])
    kwargs = {"scan_count": 10, "background_count": 10, "seed": 3} | kwargs
    dwell = simulate_dwell(
        centre, radius_m, material=material, background_m=background_m, **kwargs,  # type: ignore[arg-type]
    )
    seen = centre * (1.0 + front_range_error_m(dwell) / range_m)
    try:
        found = find_rod_centre(
            average_scans(dwell.scans),
            radius_m=radius_m,
            background=average_scans(dwell.background),
            axis_in_scanner=Z_AXIS,
        )
    except RodNotFoundError as refused:
        return refused, seen
    return found, seen


def _mahalanobis2(found: RodCentre, truth: np.ndarray) -> float:
    error = found.centre_uv_m - truth
    return float(error @ np.linalg.solve(found.covariance_uv_m2, error))


@pytest.mark.parametrize(
    ("range_m", "radius_m", "material"),
    [(0.2, 0.004, "painted"), (0.2, 0.004, "matte"), (0.1, 0.010, "matte"), (0.5, 0.010, "steel_drill")],
)
def test_a_thin_rod_with_a_wall_close_behind_is_refused_or_warned_never_silently_wrong(
    range_m: float, radius_m: float, material: str
) -> None:
    # Every beam's spot is wider than the rod (or the rod so near that the receiver barely
    # sees it): the wall 0.3 m behind merges into each echo. These returned centres 0.03 to
    # 0.25 m off as successes.
    outcome, truth = _extract(range_m, 23.0, radius_m, material, 0.3)
    if isinstance(outcome, RodNotFoundError):  # a clear skip, with its reason
        return
    assert _mahalanobis2(outcome, truth) < CHI2_2DOF_999 or outcome.warnings


@pytest.mark.parametrize(
    ("range_m", "bearing_deg", "material"), [(0.1, 20.0, "matte"), (0.15, 17.0, "steel_drill")]
)
def test_a_thin_rod_before_a_far_wall_is_found_its_beams_read_the_rod_alone(
    range_m: float, bearing_deg: float, material: str
) -> None:
    # The beam's spot is wider than the 4 mm rod, but the wall 2.5 m behind returns an echo of
    # its own (it does not merge with the rod's): every beam on the rod reads the rod. These
    # were refused as "every beam on the rod blends it with the surface 2.49 m behind it".
    found, truth = _extract(range_m, bearing_deg, 0.004, material, 2.5)
    assert isinstance(found, RodCentre)
    assert _mahalanobis2(found, truth) < CHI2_2DOF_999


@pytest.mark.parametrize("bearing_deg", [-66.0, 10.0])
def test_a_thin_taped_rod_at_a_tenth_of_a_metre_lighting_a_wide_blot_is_found(bearing_deg: float) -> None:
    # A 4 mm taped rod at 0.1 m lights the spot's faint skirt over about 19 deg of beams, all
    # within the rod's radius of one range but for the noise of the blot's nearest and
    # farthest beams: it was "no segment matching a rod".
    found, truth = _extract(0.1, bearing_deg, 0.004, "retro_tape", 2.5)
    assert isinstance(found, RodCentre)
    assert _mahalanobis2(found, truth) < CHI2_2DOF_999


@pytest.mark.parametrize("bearing_deg", [36.0, 12.0, -52.0])
def test_a_dark_rod_whose_core_keeps_blends_on_one_side_is_not_pulled_sideways(bearing_deg: float) -> None:
    # A dark 45 mm rod at 1 m with a wall 0.3 m behind: its flanks merge with the wall, and
    # the core kept blended beams (+14, +49 mm) on one side only; the known-radius fit bent
    # towards them, 10-15 mm off against a 3-4 mm std. Such an edge beam, mostly beside the
    # fitted rod while the other edge is clean, is dropped and the fit repeated.
    found, truth = _extract(1.0, bearing_deg, 0.045, "dark", 0.3)
    assert isinstance(found, RodCentre)
    assert _mahalanobis2(found, truth) < THREE_STD_M2


@pytest.mark.parametrize("bearing_deg", [36.0, -28.0])
def test_a_20_mm_rod_before_a_near_wall_with_a_blended_edge_beam_is_found(bearing_deg: float) -> None:
    # The same one-sided blend made these 'segment of 19 beams is not a rod (fit RMS 8-9 mm)'.
    found, truth = _extract(0.3, bearing_deg, 0.020, "painted", 0.3)
    assert isinstance(found, RodCentre)
    assert _mahalanobis2(found, truth) < CHI2_2DOF_999


def test_a_20_mm_rod_whose_flanks_merged_with_a_near_wall_is_fitted_on_its_middle() -> None:
    # Blended ramps on both sides (20-50 mm behind the surface) stayed in the segment and the
    # fit was "not a rod (fit RMS 7-8 mm)"; without the beams whose blend bound exceeds what a
    # rod beam may lie off its surface, its middle is a rod (the benchmark's 40-scan dwells).
    found, truth = _extract(
        0.3, 32.4, 0.020, "painted", 0.3, scan_count=40, background_count=40, seed=0, spindle_deg=7.0 * 32.4
    )
    assert isinstance(found, RodCentre)
    # 99.9 % of an honest covariance's distances: with the systematic covariance no longer
    # padded (branch honest) this centre lies at 3.5 std (squared distance 12.5).
    assert _mahalanobis2(found, truth) < CHI2_2DOF_999


@pytest.mark.parametrize("bearing_deg", [-20.0, 28.0, 60.0])
def test_a_dark_rod_before_a_far_wall_showing_only_its_middle_is_found(bearing_deg: float) -> None:
    # A dark 10 mm rod at 0.15 m: the wall 2.5 m behind outshines its grazing flanks, so only
    # the middle 11-12 of its 27 beams read it, under the 60 % of its width a candidate had to
    # span: "no segment matching a rod". Its nearly flat arc's sideways position is checked
    # against the profile's symmetry (60 deg: 6 mm sideways against 1.5 mm std without it).
    found, truth = _extract(0.15, bearing_deg, 0.010, "dark", 2.5)
    assert isinstance(found, RodCentre)
    assert _mahalanobis2(found, truth) < CHI2_2DOF_999


@pytest.mark.parametrize(
    ("range_m", "material", "must_find"),
    [(0.2, "matte", False), (0.2, "painted", True), (0.5, "painted", True)],
)
def test_a_20_mm_rod_with_ramps_into_a_near_wall_is_found_with_an_honest_covariance(
    range_m: float, material: str, must_find: bool
) -> None:
    # Its edge beams ramp into the wall 0.3 m behind; these were "not a rod (fit RMS 5-15 mm)".
    # At 0.2 m the matte rod's ramps are still sometimes too much for the fit: then a clear skip.
    found, truth = _extract(range_m, -31.0, 0.020, material, 0.3)
    if isinstance(found, RodNotFoundError) and not must_find:
        assert "is not a rod" in str(found)
        return
    assert isinstance(found, RodCentre)
    assert _mahalanobis2(found, truth) < CHI2_2DOF_999


@pytest.mark.parametrize(("range_m", "radius_m"), [(0.2, 0.010), (0.2, 0.004)])
def test_a_near_thin_rod_before_a_far_wall_looks_a_spot_wider_and_is_found(
    range_m: float, radius_m: float
) -> None:
    # Its echo wins over the wall 2.5 m behind while any of the spot touches it, so the rod
    # spans the spot's width more beams than its own: this was "no segment matching a rod".
    found, truth = _extract(range_m, 12.0, radius_m, "matte", 2.5)
    assert isinstance(found, RodCentre)
    assert _mahalanobis2(found, truth) < CHI2_2DOF_999


def test_a_far_rod_of_few_beams_is_found() -> None:
    found, truth = _extract(3.0, -8.0, 0.045, "painted", 2.5)
    assert isinstance(found, RodCentre)
    assert found.quality.beams_used >= 3
    assert _mahalanobis2(found, truth) < CHI2_2DOF_999


@pytest.mark.parametrize(("range_m", "bearing_deg"), [(0.6, 17.0), (1.0, -36.0)])
def test_issue_18s_taped_rod_with_steady_ramps_is_found_with_an_honest_covariance(
    range_m: float, bearing_deg: float
) -> None:
    # Issue 18's rod (45 mm, retro-reflective tape) at 0.5-1.1 m with a wall behind: 4-16
    # steady blended beams ramp out on each side and its bright halo widens it; it was found
    # in 0 of 4 real scans ("no segment matching a rod").
    found, truth = _extract(range_m, bearing_deg, 0.045, "retro_tape", 0.3)
    assert isinstance(found, RodCentre)
    assert _mahalanobis2(found, truth) < CHI2_2DOF_999


@pytest.mark.parametrize("range_m", [0.15, 0.3])
def test_issue_18s_taped_rod_near_the_scanner_is_found_or_skipped_never_silently_wrong(
    range_m: float,
) -> None:
    # Dozens of beams, the near-range error and the receiver barely seeing the rod: 8 of 13
    # real scans were "not a rod (fit RMS 17-36 mm)".
    found, truth = _extract(range_m, -9.0, 0.045, "retro_tape", 2.5)
    if isinstance(found, RodNotFoundError):
        return
    assert found.quality.beams_used >= 20
    assert _mahalanobis2(found, truth) < CHI2_2DOF_999 or found.warnings


def test_issue_18s_taped_rod_far_away_keeps_its_flaky_edge_beams() -> None:
    # At 2.95 m five beams hit it and its two edge beams answer in about 70 % of the scans:
    # trimmed as unstable, three were left, under the minimum width.
    found, truth = _extract(2.95, 4.0, 0.045, "retro_tape", 2.5)
    assert isinstance(found, RodCentre)
    assert found.quality.beams_used >= 4
    assert _mahalanobis2(found, truth) < CHI2_2DOF_999


@pytest.mark.parametrize(
    ("range_m", "bearing_deg", "radius_m", "material", "background_m"),
    [
        (0.5, 34.7, 0.010, "matte", 2.5),  # a halo 19 beams wide around a 9-beam rod
        (0.75, 13.8, 0.020, "bare_metal", 0.3),  # merged with the wall: 5 beams left to fit
        (0.1, 12.5, 0.045, "dark", 0.3),  # a wide flat front, near-range ramps on both sides
        (1.0, 32.7, 0.045, "dark", 2.5),  # repeated steps drag the arc sideways
    ],
)
def test_centres_the_benchmark_found_silently_off_are_now_covered(
    range_m: float, bearing_deg: float, radius_m: float, material: str, background_m: float
) -> None:
    # Each of these came back 2-20 mm sideways against a reported std of 0.3-6 mm (the
    # benchmark's dwells: 40 scans, its seed and tool turn).
    found, truth = _extract(
        range_m, bearing_deg, radius_m, material, background_m,
        scan_count=40, background_count=40, seed=0, spindle_deg=7.0 * bearing_deg,
    )
    if isinstance(found, RodNotFoundError):
        return
    assert _mahalanobis2(found, truth) < CHI2_2DOF_999 or found.warnings


def test_a_rod_sized_post_elsewhere_without_an_expected_position_is_never_taken_for_the_rod() -> None:
    # No background scan: the post stays in view. Both are named, or the rod is returned.
    bearing = np.radians(14.0)
    truth = 0.8 * np.array([np.cos(bearing), np.sin(bearing)])
    post = 0.8 * np.array([np.cos(np.radians(-58.0)), np.sin(np.radians(-58.0))])
    dwell = simulate_dwell(
        truth, 0.045, background_m=1.5, posts=[(post[0], post[1], 0.045)], scan_count=10, seed=4
    )
    try:
        found = find_rod_centre(average_scans(dwell.scans), radius_m=0.045, axis_in_scanner=Z_AXIS)
    except RodNotFoundError as refused:
        assert "2 rod-like objects in view" in str(refused)
        assert "-58 deg" in str(refused)
        return
    assert np.linalg.norm(found.centre_uv_m - truth) < 0.03  # within the model's range bias


@pytest.mark.parametrize(("range_m", "bearing_deg"), [(0.15, 21.0), (0.15, -57.0), (0.1, 38.0)])
def test_a_thin_taped_rod_before_a_near_wall_is_warned_or_covered_never_silently_long(
    range_m: float, bearing_deg: float
) -> None:
    # The 4 mm rod is a third of the beam's spot: every beam returns the wall 0.3 m behind too,
    # dimmed by the tape's brightness to 2-4 % of the echo (under the 5 % that put the blend
    # bound into the covariance), which pushed every beam 3 mm long and the centre 3-7 mm long
    # against 0.8-1.5 mm std, without a warning (the benchmark's dwells: 40 scans).
    found, truth = _extract(
        range_m, bearing_deg, 0.004, "retro_tape", 0.3,
        scan_count=40, background_count=40, seed=0, spindle_deg=7.0 * bearing_deg,
    )
    if isinstance(found, RodNotFoundError):
        return
    assert _mahalanobis2(found, truth) <= THREE_STD_M2 or found.warnings


def test_a_far_rod_of_few_beams_before_a_near_wall_carries_its_edge_beams_blend() -> None:
    # 3 beams on a 45 mm rod at 3 m; the spot (53 mm) of each edge beam reaches the wall 0.3 m
    # behind, whose echo merges with the rod's and reads it long, and the ramps beside the rod
    # (split off its segment by their range jumps) show that the spot does. The fit has one
    # spare beam and cannot see it: 2.7 mm long against 0.9 mm std, 4.2 std, without a warning.
    found, truth = _extract(
        3.0, -57.3, 0.045, "painted", 0.3,
        scan_count=40, background_count=40, seed=0, spindle_deg=7.0 * -57.3,
    )
    assert isinstance(found, RodCentre)
    assert _mahalanobis2(found, truth) <= THREE_STD_M2 or found.warnings


@pytest.mark.parametrize(("material", "bearing_deg"), [("bare_metal", 41.6), ("steel_drill", 30.4)])
def test_a_shiny_rod_whose_flanks_merged_with_a_near_wall_is_found_on_its_middle(
    material: str, bearing_deg: float
) -> None:
    # A 20 mm bare-metal or steel rod at 0.2 m, the wall 0.3 m behind: the wall outshines the
    # rod's flanks, whose beams step out to it in 25-70 mm steps that split them off the rod's
    # segment; the 13-14 beams left read the rod (within 3 mm) but span a third of its width,
    # under the 60 % a segment had to span: "no segment matching a rod" (the benchmark's
    # dwells: 40 scans, its seed and tool turn).
    found, truth = _extract(
        0.2, bearing_deg, 0.020, material, 0.3,
        scan_count=40, background_count=40, seed=0, spindle_deg=7.0 * bearing_deg,
    )
    assert isinstance(found, RodCentre)
    assert _mahalanobis2(found, truth) <= THREE_STD_M2 or found.warnings


def test_a_near_rod_whose_every_beam_a_bright_wall_close_behind_pushes_long_is_warned() -> None:
    # A matte 20 mm rod at 0.1 m: the wall 0.3 m behind returns 16 times the rod's power per
    # unit of spot (the receiver barely sees the rod), and the spot's faint halo merges it into
    # every beam: the middle beams read 4-5 mm long, the centre 4.7-8.7 mm long against 0.6-1.9
    # mm std, without a warning.
    found, truth = _extract(
        0.1, -35.5, 0.020, "matte", 0.3, scan_count=40, background_count=40, seed=0, spindle_deg=7.0 * -35.5,
    )
    if isinstance(found, RodNotFoundError):
        return
    assert _mahalanobis2(found, truth) <= THREE_STD_M2 or found.warnings


@pytest.mark.parametrize(
    ("range_m", "bearing_deg", "radius_m", "material"),
    [
        (0.3, -54.7404, 0.010, "steel_drill"),  # every beam blends: a jagged middle 35 mm behind it
        (0.1, 12.53, 0.045, "dark"),  # the halo lifts the clean edge: blends kept on one side
    ],
)
def test_a_rod_blended_with_a_near_wall_is_never_found_silently_off_on_a_part_of_its_blends(
    range_m: float, bearing_deg: float, radius_m: float, material: str
) -> None:
    # Found by a first version of the narrow middle and the spot's halo: 40.8 mm long (fitted
    # through the far side of a circle) and 10.9 mm sideways, both without a warning.
    found, truth = _extract(
        range_m, bearing_deg, radius_m, material, 0.3,
        scan_count=40, background_count=40, seed=0, spindle_deg=7.0 * bearing_deg,
    )
    if isinstance(found, RodNotFoundError):
        return
    assert _mahalanobis2(found, truth) <= THREE_STD_M2 or found.warnings


#: A polished 10 mm bit at 0.54 m, a wall this far behind it (m), at this bearing (deg).
PULSE_WALLS = [(0.9, 10.0), (1.0, 23.0), (1.1, -31.0), (1.2, 10.0)]


@pytest.mark.parametrize(("background_m", "bearing_deg"), PULSE_WALLS)
def test_a_polished_bit_a_pulse_length_before_a_wall_is_never_silently_long(
    background_m: float, bearing_deg: float
) -> None:
    # The drill job's outliers (docs/extraction.md, "The pull a pulse length behind"): a polished
    # 10 mm bit at 0.54 m returns little light, and a wall 0.9-1.2 m behind, beyond the 0.85 m
    # where echoes merge, still pulls each beam's echo peak long through the laser pulse. These
    # were found 8-51 mm long against 0.7-4.5 mm std, without a warning.
    found, truth = _extract(0.54, bearing_deg, 0.005, "steel_drill", background_m)
    if isinstance(found, RodNotFoundError):
        return
    assert _mahalanobis2(found, truth) <= THREE_STD_M2 or found.warnings


@pytest.mark.parametrize(("background_m", "bearing_deg"), PULSE_WALLS)
def test_most_of_the_pull_a_pulse_length_behind_a_polished_bit_is_taken_out(
    background_m: float, bearing_deg: float
) -> None:
    # The same bits: with three quarters of each beam's estimated pull out of its range they lie
    # 1.0-4.4 mm from the truth (8-51 mm with the pull left in).
    found, truth = _extract(0.54, bearing_deg, 0.005, "steel_drill", background_m)
    assert not isinstance(found, RodNotFoundError)
    assert np.linalg.norm(np.asarray(found.centre_uv_m) - truth) < 0.005


def _benchmark_dwell(
    range_m: float, bearing_deg: float, radius_m: float, material: str, background_m: float
) -> tuple[RodCentre | RodNotFoundError, np.ndarray]:
    """The benchmark's dwell at one of its positions (40 scans, its seed 0 and tool turn)."""
    return _extract(
        range_m, bearing_deg, radius_m, material, background_m,
        scan_count=40, background_count=40, seed=0, spindle_deg=7.0 * bearing_deg,
    )


@pytest.mark.parametrize(
    ("range_m", "bearing_deg", "material", "background_m"),
    [
        # The wall merges into the edge beams, which read long where the spot model says short:
        # the ray fit won, 1.25 mm long against 0.29 mm std.
        (1.5, 11.2657, "matte", 0.3),
        (2.0, 7.5532, "painted", 2.5),  # 2.7 mm sideways against 0.85 mm std: edges lit unevenly
        (0.5, 4.8256, "dark", 2.5),  # 1.1 mm long against 0.48 mm: its edges read the curve deeper
    ],
)
def test_a_thick_rods_centre_the_benchmark_found_silently_off_is_covered(
    range_m: float, bearing_deg: float, material: str, background_m: float
) -> None:
    # The benchmark's last silent centres on its default seed (45 mm rods, 3.3-4.4 std).
    found, truth = _benchmark_dwell(range_m, bearing_deg, 0.045, material, background_m)
    assert isinstance(found, RodCentre)
    assert _mahalanobis2(found, truth) <= THREE_STD_M2 or found.warnings


def test_a_centre_placed_by_its_echo_middle_is_uncertain_along_its_own_bearing() -> None:
    # The benchmark's polished 45 mm rod at 0.1 m before the near wall (seed 0, 2026-11-29): the
    # fit lay 9 mm aside, the echo middle placed the centre on its true bearing and 12 mm long,
    # and the covariance kept the fit's bearing for its 10 mm along: an ellipse 5 deg off, 8 std.
    found, truth = _benchmark_dwell(0.1, float(np.degrees(-0.060)), 0.045, "steel_drill", 0.3)
    assert isinstance(found, RodCentre)
    assert found.echo_middle_move_uv_m is not None and np.linalg.norm(found.echo_middle_move_uv_m) > 0.005
    _, eigenvectors = np.linalg.eigh(found.covariance_uv_m2)
    bearing = found.centre_uv_m / np.linalg.norm(found.centre_uv_m)
    assert abs(float(eigenvectors[:, 1] @ bearing)) > np.cos(np.radians(0.5))
    assert _mahalanobis2(found, truth) <= THREE_STD_M2 or found.warnings


@pytest.mark.parametrize(("range_m", "bearing_deg"), [(0.55, 10.0), (0.45, 40.0)])
def test_a_thin_rods_centre_moves_from_dwell_to_dwell_only_as_its_noise_covariance_says(
    range_m: float, bearing_deg: float
) -> None:
    # The drill job's 10 mm rod at 0.3-0.6 m (docs/lab/verify-log.md, 2026-11-27, drillverify): the fit
    # against the spot wandered sideways in some dwells and was refused, and the fits chose
    # between the spot's range and the rays' (about 1 mm apart) anew at every dwell, while the
    # noise covariance said 0.15-0.5 mm: verify flagged unmoved scanners. Pairs of dwells at one
    # pose differ by what the two noise covariances say: 2 on average (3.25 and 3.45 before, on 8
    # pairs); over 32 pairs the mean's std is 0.35, so 2.8 is 2.3 std above it.
    bearing = np.radians(bearing_deg)
    centre = range_m * np.array([np.cos(bearing), np.sin(bearing)])
    found = []
    for seed in range(64):
        dwell = simulate_dwell(centre, 0.005, background_m=None, scan_count=40, seed=seed)
        scan = average_scans(dwell.scans)
        found.append(find_rod_centre(scan, radius_m=0.005, axis_in_scanner=Z_AXIS, expected_uv_m=centre))
    squared = []
    for first, second in zip(found[::2], found[1::2], strict=True):
        assert first.noise_covariance_uv_m2 is not None and second.noise_covariance_uv_m2 is not None
        difference = first.centre_uv_m - second.centre_uv_m
        noise = first.noise_covariance_uv_m2 + second.noise_covariance_uv_m2
        squared.append(float(difference @ np.linalg.solve(noise, difference)))
    assert float(np.mean(squared)) < 2.8, squared


@pytest.mark.parametrize(
    ("range_m", "bearing_deg", "side", "near_behind_m"),
    [(0.3, 33.0, -1, 0.56), (0.4, 5.1, 1, 0.52), (0.5, -0.57, -1, 0.72), (0.5, 47.27, 1, 0.95)],
)
def test_a_rod_before_a_step_behind_one_edge_is_never_silently_sideways(
    range_m: float, bearing_deg: float, side: int, near_behind_m: float
) -> None:
    # The extraction benchmark's uneven background (docs/lab/extraction-log.md, "Backgrounds not
    # square to the bearing"): a 10 mm steel rod before a wall 0.5-1 m behind that ends behind one of
    # its edges, a wall 2 m behind on the other side. The spot blends the edge beams with the
    # two unequally and the centre moved 2.5-5 mm away from the near side against 0.6-1.3 mm
    # of reported std (3.4-6.7 std), without a warning.
    bearing = np.radians(bearing_deg)
    centre = range_m * np.array([np.cos(bearing), np.sin(bearing)])
    found, truth = _extract(
        range_m, bearing_deg, 0.010, "steel_drill", None,
        walls=step_behind_edge(centre, 0.010, side, near_behind_m, 2.0),
        scan_count=40, background_count=40, seed=0, spindle_deg=7.0 * bearing_deg,
    )
    assert isinstance(found, RodCentre)
    assert _mahalanobis2(found, truth) <= THREE_STD_M2 or found.warnings


@pytest.mark.parametrize(
    ("radius_m", "bearing_deg", "side"),
    [(0.010, 10.0, 1), (0.010, 35.0, -1), (0.0225, -20.0, 1), (0.0225, 10.0, -1)],
)
def test_a_rod_with_a_wall_behind_one_edge_and_open_space_beside_the_other_is_not_moved_sideways(
    radius_m: float, bearing_deg: float, side: int
) -> None:
    # The dry run's waypoint 18 (docs/lab/extraction-log.md, `edgek` and `intmid2`): behind one edge a
    # surface whose echo outshines the rod's spot sooner than what lies behind the other (there:
    # a wall's foot and the floor at grazing incidence; here a wall 1.5 m behind and nothing),
    # so the rod's echo wins further out on the dark side, the segment reaches further there, and
    # the known-radius fit followed it: 2.5-5.9 mm sideways (0.7-2.5 reported std), every time.
    # The middle of the rod's intensity lobe is not moved by which echo wins at the edges.
    bearing = np.radians(bearing_deg)
    centre = 0.32 * np.array([np.cos(bearing), np.sin(bearing)])
    found, truth = _extract(
        0.32, bearing_deg, radius_m, "painted", None,
        walls=step_behind_edge(centre, radius_m, side, 1.5, 3.0)[:1],
        scan_count=40, background_count=40, seed=0,
    )
    assert isinstance(found, RodCentre)
    across = np.array([-np.sin(bearing), np.cos(bearing)])
    assert abs(float(across @ (found.centre_uv_m - truth))) < 0.001
    assert _mahalanobis2(found, truth) <= THREE_STD_M2


@pytest.mark.parametrize("bearing_deg", [-33.3, 15.0])
def test_a_polished_rod_on_few_beams_is_not_placed_short_by_its_glint(bearing_deg: float) -> None:
    # A 45 mm steel rod 3 m away (5-7 beams, the spot about as wide as the rod): each beam's
    # echo is the glint from the section's front, so the beams read about one range and the
    # spot fit, weighting a diffuse section, put the centre 3.7-4.3 mm short (main: 10.9 and 4.5
    # squared std; over 60 dwells 2.40 mm short on average, 6 more than 3 std off, silent).
    found, truth = _extract(3.0, bearing_deg, 0.045, "steel_drill", 2.5, scan_count=20, background_count=20)
    assert isinstance(found, RodCentre)
    bearing = truth / np.linalg.norm(truth)
    assert abs(float(bearing @ (found.centre_uv_m - truth))) < 0.002
    assert _mahalanobis2(found, truth) <= THREE_STD_M2


def test_a_diffuse_rod_on_few_beams_keeps_its_fit_along_the_bearing() -> None:
    # The glint's placement is for polished rods only: a painted 20 mm rod at 1.5 m (6 beams)
    # reads an echo that falls off across it as a diffuse section's.
    bearing = np.radians(12.0)
    dwell = simulate_dwell(
        1.5 * np.array([np.cos(bearing), np.sin(bearing)]), 0.020, material="painted",
        background_m=2.5, scan_count=20, background_count=20, seed=3,
    )
    scan, background = average_scans(dwell.scans), average_scans(dwell.background)
    centres = [
        find_rod_centre(scan, radius_m=0.020, background=background, axis_in_scanner=Z_AXIS, settings=chosen)
        for chosen in (ExtractionSettings(), ExtractionSettings(glint_gloss_ratio=0.0))
    ]
    assert centres[0].quality.beams_used <= ExtractionSettings().glint_max_beams
    np.testing.assert_array_equal(centres[0].centre_uv_m, centres[1].centre_uv_m)
    np.testing.assert_array_equal(centres[0].covariance_uv_m2, centres[1].covariance_uv_m2)


@pytest.mark.parametrize(("range_m", "bearing_rad"), [(0.15, -0.683), (0.3, 1.028)])
def test_a_twist_drill_whose_flutes_split_its_echo_is_one_rod_not_two(
    range_m: float, bearing_rad: float
) -> None:
    """The extraction benchmark's seed 100: a 4 mm bit's flutes split its echo into two segments
    whose fits lie 5-6 mm apart, more than a radius; two rods of that radius cannot lie closer
    than a diameter, so they are one rod, not "2 rod-like objects in view"."""
    centre = range_m * np.array([np.cos(bearing_rad), np.sin(bearing_rad)])
    dwell = simulate_dwell(
        centre, 0.004, material="steel_drill", shape="twist_drill", background_m=2.5, scan_count=40,
        background_count=40, seed=100, spindle_deg=float(np.degrees(bearing_rad) * 7.0),
    )
    seen = centre * (1.0 + front_range_error_m(dwell) / range_m)
    found = find_rod_centre(
        average_scans(dwell.scans), radius_m=0.004, background=average_scans(dwell.background),
        axis_in_scanner=Z_AXIS, fluted=True,
    )
    assert _mahalanobis2(found, seen) <= THREE_STD_M2 or found.warnings
