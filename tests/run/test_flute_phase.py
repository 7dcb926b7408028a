"""The flute phase pass: synthetic centres of a twist drill that turns with the tool."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from benchmarks.dry_run_accuracy import measure_waypoints, world_for
from lasercal_hw.calibration.flutes import flute_offsets_m, glint_offsets
from lasercal_hw.calibration.model import plane_crossing, rod_lines_in_base
from lasercal_hw.calibration.solver import SolverOptions, solve
from lasercal_hw.config import load_job
from lasercal_hw.models import Observation
from lasercal_hw.run import two_pass
from lasercal_hw.run.flute_phase import (
    MODEL_ALLOWANCE_RADIUS_FRACTION,
    PLAIN_EXTRACTION,
    estimate_flute_phase,
    profile_spread_rad,
)
from lasercal_hw.run.waypoints import listed_waypoints

DRILL_JOB = Path(__file__).resolve().parents[2] / "examples" / "drill.toml"
SIGMA_M = 0.0003


@pytest.fixture(scope="module")
def drill():
    """The drill job, its waypoints, its nominal pose as the truth and its solver options."""
    job = load_job(DRILL_JOB)
    options = SolverOptions(robot_sigma_m=0.0002, estimate_axis=False, estimate_range_offset=False)
    return job.rod.rod_line(), listed_waypoints(job), job.scanner.nominal.matrix(), options


def _centres(rod, poses, truth, phase_rad, rng, flutes=True):
    """Plain fits of the drill's section at every waypoint: the crossing, the section's offset
    at the bit's turn (phase ``phase_rad``) and a little noise."""
    origins, directions = rod_lines_in_base(poses, rod)
    crossing, _, _ = plane_crossing(truth[:3, :3], truth[:3, 3], origins, directions)
    if flutes:
        crossing = crossing + flute_offsets_m(phase_rad, truth, poses, rod)
    centres = crossing + rng.normal(0.0, SIGMA_M, crossing.shape)
    return [Observation(i, poses[i], centres[i], np.eye(2) * SIGMA_M**2) for i in range(len(poses))]


def _error_mm(result, truth) -> float:
    return float(np.linalg.norm(result.matrix()[:3, 3] - truth[:3, 3]) * 1e3)


def test_glint_offsets_land_facing_is_on_axis_flute_facing_lies_behind():
    """A land facing the scanner: the fit is on the axis; a flute's middle facing it: the
    fit lies (1 - web) r behind the axis, straight along the bearing; point-symmetric."""
    offsets = glint_offsets(np.radians([90.0, 0.0, 180.0, 20.0, 200.0]))
    assert np.allclose(offsets[0], 0.0)
    assert offsets[1] == pytest.approx([-(1.0 - 0.16), 0.0])
    assert offsets[2] == pytest.approx([1.0 - 0.16, 0.0])
    assert offsets[4] == pytest.approx(-offsets[3])


def test_phase_pass_recovers_the_phase_and_the_pose(drill):
    """Centres of a twist drill at a phase the run does not know: a plain solve is off by
    millimetres; the phase pass finds the phase and the pose within the noise. The pass starts,
    as in a run, from the solution on centres widened by the model's allowance (taken as they
    are, 19 of the job's 40 centres would fail the outlier test)."""
    rod, poses, truth, options = drill
    rng = np.random.default_rng(3)
    true_phase_deg = 72.0
    plain = _centres(rod, poses, truth, np.radians(true_phase_deg), rng)
    allowance = np.eye(2) * (MODEL_ALLOWANCE_RADIUS_FRACTION * rod.radius_m) ** 2
    widened = [replace(o, covariance_uv_m2=o.covariance_uv_m2 + allowance) for o in plain]
    naive = solve(widened, replace(rod, fluted=False), options=options)
    found = estimate_flute_phase(plain, naive, rod, options)
    assert found is not None
    wrapped = (found.phase_deg - true_phase_deg + 90.0) % 180.0 - 90.0
    assert abs(wrapped) < max(3.0 * found.phase_std_deg, 3.0)
    assert _error_mm(naive, truth) > 1.0
    assert _error_mm(found.result, truth) < 0.5 * _error_mm(naive, truth)


def test_phase_pass_refuses_a_bit_without_flutes(drill):
    """A round bit's centres carry no phase: the profile is flat and the pass gives way."""
    rod, poses, truth, options = drill
    plain = _centres(rod, poses, truth, 0.0, np.random.default_rng(4), flutes=False)
    plain = [replace(o, covariance_uv_m2=np.eye(2) * 0.002**2) for o in plain]
    widened = solve(plain, rod, options=options)
    assert estimate_flute_phase(plain, widened, rod, options) is None


def test_phase_std_spans_every_valley_of_the_profile():
    """A profile with a second valley 2 in chi-square above the best, 40 deg away, gives a std
    of that order, not the best valley's own width; one sharp valley keeps a small std."""
    phases = np.radians(np.arange(0.0, 180.0, 4.0))
    sharp = 5000.0 * ((phases - np.radians(80.0) + np.pi / 2) % np.pi - np.pi / 2) ** 2
    assert np.degrees(profile_spread_rad(phases, sharp, np.radians(80.0))) < 4.0
    jagged = np.minimum(sharp, 2.0 + 5000.0 * ((phases - np.radians(120.0)) ** 2))
    assert np.degrees(profile_spread_rad(phases, jagged, np.radians(80.0))) > 10.0


def test_the_phase_pass_gets_plain_centres_with_the_range_offset_out_once(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The flute phase pass's plain fits take the first pass's range offset out of the ranges as
    the second pass did, and are not moved back by it a second time (which shifted every centre
    by the offset, ~9 mm on the drill job, and the reported range curve with it)."""
    job = load_job(DRILL_JOB)
    rng = np.random.default_rng(100)
    world = world_for(job, None, robot_error_seed=1100)
    measurements, background = measure_waypoints(job, listed_waypoints(job), world, 10, rng)
    seen: dict[str, object] = {}

    def capture(plain, widened, rod, options):
        seen.update(plain=list(plain), widened=widened, rod=rod)
        return None

    monkeypatch.setattr(two_pass, "estimate_flute_phase", capture)
    solution = two_pass.solve_two_pass(measurements, job, background)
    applied_m = solution.refit.range_offset_m
    assert abs(applied_m) > 0.002
    plain_rod = replace(seen["widened"].estimated_rod(job.rod.rod_line()), fluted=False)
    once, kept = two_pass.refit_centres(
        measurements, seen["widened"].matrix(), plain_rod, background,
        range_offset_m=applied_m, settings=PLAIN_EXTRACTION,
    )
    kept_indices = {index for index, _ in kept}
    refitted = [m for m in once if m.index not in kept_indices]
    assert len(refitted) >= 10
    by_index = {o.index: o for o in seen["plain"]}
    np.testing.assert_allclose(
        [by_index[m.index].centre_uv_m for m in refitted], [m.centre.centre_uv_m for m in refitted], atol=1e-9
    )
