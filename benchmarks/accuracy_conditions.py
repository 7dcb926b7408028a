"""Accuracy under real conditions (issue 13): short dwell, a drill bit off its nominal
axis, a scanner range offset. Offline, through the fake cell's world; not collected by pytest.

Run from the repository root::

    .venv/bin/python -m benchmarks.accuracy_conditions [--seeds 20] [--first-seed 0]
        [--cases default-3s,drill-estimated]
        [--model physical|ideal] [--design-seed 0] [--design-range-terms K] [--design-waypoints 20]
        [--noise-stream K] [--waypoints-file FILE] [--per-waypoint]

Each case runs the sequencer's measurement chain (``benchmarks.dry_run_accuracy.simulate``:
noisy scans of the world at every waypoint, averaging, extraction with the background,
the two-pass solve) once per seed; every seed draws new scan noise and a new robot
absolute-accuracy error field. Cases:

* ``default-3s``, ``default-1s``, ``default-0.5s``: the default job (``paper`` preset, 20 mm
  rod) on the default scene with 3, 1 and 0.5 s dwell;
* ``designed-1s``, ``designed-0.5s``: the same rod and dwell 1 s and 0.5 s on the 20
  waypoints ``lasercal trajectory design`` lays out for the scene's scanner;
* ``drill-known``: the drill job (``examples/drill.toml``: waypoints designed for the cell with
  the bit's axis estimated) with the bit exactly where the job file says, the axis not
  estimated (the reference);
* ``drill-fixed``, ``drill-estimated``: the same job whose real bit is 2 mm off and tilted
  1 degree from the job file's axis, solved with the job's axis (the bias it causes) and
  with ``rod.estimate_axis = true``; the bit is the default scene's rod of the bit's radius
  (a painted cylinder), so these cases visit the waypoints as listed, without the job's spin;
* ``drill-fluted``: the drill job as shipped (its spin, then its waypoints turned to the bit's
  flute phase) on the scene that holds the bit as it is (``fakes/scenes/drill.toml``: a fluted
  10 mm twist drill of ground steel in a collet chuck, turned with the tool);
* ``drill-fluted-any-turn``: the same, the bit turned in its chuck by an angle drawn per seed
  (uniform over 0-180 deg, a two-fluted bit's period): a real bit sits in its chuck at any
  turn, and ``drill-fluted``'s one turn may suit the shipped waypoints' tool turns by chance;
* ``drill-preset-estimated``: the same bit and estimation on the ``drill`` preset's
  semicircles, which keep the tool's turn about the bit nearly constant (why the drill job
  uses designed waypoints);
* ``offset-off``, ``offset-default``: the default job on a scanner reading 20 mm long, with
  ``scanner.estimate_range_offset = false`` and with the job's default (``auto``, which
  estimates it on these waypoints); the ``default-*`` cases run with that default too;
* ``curve-off``, ``curve-offset``, ``curve-default``: a scanner whose range error changes
  with distance (``CURVE``: +8 mm at the scanner, -5.5 mm per metre, a 3 mm ripple over
  2.5 m: within +-8 mm over the cell, the data sheet allows 30), solved without any range
  error, with an offset alone (``scanner.range_error_terms = 1``, the solver before issue
  18) and with the job's default curve.

Printed per case: waypoints found, the translation (mm) and rotation (deg) error against
the truth (median, 95th percentile, max), the share of error components within 2.5
reported std, and the estimated axis / range offset against the truth in reported std.
The default (5 seeds) is a quick look; the figures in docs/solver.md use ``--seeds 50``.
``--model``: the scene's scanner model (``physical``, its default: a real UTM-30LX-EW's
footprint, echoes and range error; or ``ideal``, the reference). ``--design-seed``,
``--design-range-terms`` and ``--design-waypoints``: another design of the ``designed-*``
cases (one design is one draw: docs/lab/trajectory-design-log.md compares several).
``--noise-stream K``: the scanner noise of every seed drawn from stream K (0, the default: the
figures published so far, to the digit; the worlds, robot error fields and chuck turns unchanged),
so that a 95th percentile can be given over several streams of the same seeds.
``--waypoints-file``: the cases that visit a job's waypoint file (the drill cases) visit this
file instead (a new design tried before it is shipped). ``--per-waypoint``: also every
waypoint's solved centre against the rod's true crossing over the seeds, along and across the
bearing, beside its reported std (``benchmarks.waypoint_errors``): a waypoint whose error repeats
at every seed is an extraction error at that pose.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from benchmarks.dry_run_accuracy import Trial, simulate, world_with
from benchmarks.waypoint_errors import WaypointError, print_waypoint_errors, waypoint_errors
from fakes.scene import Scene, load_scene
from lasercal_hw.calibration.model import extended_fisher_information, moved_rod
from lasercal_hw.calibration.result import RangeOffset, RodAxisEstimate
from lasercal_hw.calibration.solver import axis_deviation
from lasercal_hw.config import JobConfig, load_job, with_overrides
from lasercal_hw.errors import LasercalError
from lasercal_hw.geometry import euler_zyx_to_matrix, make_transform
from lasercal_hw.models import RodLine
from lasercal_hw.run.waypoints import job_waypoints, planned_waypoints, without_spin
from lasercal_hw.ur_kinematics import UR5
from trajectories.design import design, request_for_job

ROOT = Path(__file__).resolve().parent.parent
DRILL_JOB = ROOT / "examples" / "drill.toml"
DRILL_SCENE = ROOT / "fakes" / "scenes" / "drill.toml"
#: The real bit against the job file's axis: 2 mm across it and 1 degree of tilt, both at 45 deg.
BIT_OFFSET_M = 0.002
BIT_TILT_DEG = 1.0
RANGE_OFFSET_M = 0.020
#: The world's range bias of the curve cases: offset (m), per metre, ripple (m) and its period (m).
CURVE = {"bias_offset_m": 0.008, "bias_per_m": -0.0055, "bias_ripple_m": 0.003, "bias_ripple_period_m": 2.5}
ROBOT_ERROR_SEED_BASE = 1000
#: Seeds the bit's turn in its chuck of ``drill-fluted-any-turn`` (one draw per seed).
CHUCK_TURN_SEED_BASE = 2000


@dataclass(frozen=True)
class Case:
    """One condition: the job solved, the rod in the world, and the world's range offset."""

    name: str
    job: JobConfig
    true_rod: RodLine
    dwell_s: float
    range_offset_m: float = 0.0
    #: The world's range bias over distance (``[noise]`` bias settings), instead of the offset.
    bias: dict[str, float] | None = None
    #: Waypoints from ``lasercal trajectory design`` for the scene instead of the job's.
    designed: bool = False
    #: The scene (None: the packaged default); its rod's material and shape are kept.
    scene_path: Path | None = None
    #: Turn the twist drill in its chuck by an angle drawn per seed (0-180 deg).
    chuck_turn_drawn: bool = False


def real_bit(nominal: RodLine) -> RodLine:
    """The drill bit as it really sits: off and tilted from the job file's axis."""
    c = np.sqrt(0.5)
    step = np.array(
        [BIT_OFFSET_M * c, BIT_OFFSET_M * c, np.radians(BIT_TILT_DEG) * c, np.radians(BIT_TILT_DEG) * c]
    )
    return moved_rod(nominal, step)


def cases() -> list[Case]:
    """Every case of the module docstring."""
    default = load_job(None)
    drill = load_job(DRILL_JOB)
    listed = without_spin(drill)  # a painted cylinder's cases: no flutes for a spin to tell
    drill_fixed = with_overrides(listed, {"rod.estimate_axis": False})
    preset = listed.trajectory.model_copy(update={"preset": "drill", "waypoints_file": None})
    drill_preset = listed.model_copy(update={"trajectory": preset})
    bit = real_bit(drill.rod.rod_line())
    offset_off = with_overrides(default, {"scanner.estimate_range_offset": False})
    offset_only = with_overrides(default, {"scanner.range_error_terms": 1})
    return [
        Case("default-3s", default, default.rod.rod_line(), 3.0),
        Case("default-1s", default, default.rod.rod_line(), 1.0),
        Case("default-0.5s", default, default.rod.rod_line(), 0.5),
        Case("designed-1s", default, default.rod.rod_line(), 1.0, designed=True),
        Case("designed-0.5s", default, default.rod.rod_line(), 0.5, designed=True),
        Case("drill-known", drill_fixed, drill.rod.rod_line(), drill.dwell_s),
        Case("drill-fixed", drill_fixed, bit, drill.dwell_s),
        Case("drill-estimated", listed, bit, drill.dwell_s),
        Case("drill-fluted", drill, bit, drill.dwell_s, scene_path=DRILL_SCENE),
        Case(
            "drill-fluted-any-turn", drill, bit, drill.dwell_s, scene_path=DRILL_SCENE, chuck_turn_drawn=True
        ),
        Case("drill-preset-estimated", drill_preset, bit, drill.dwell_s),
        Case("offset-off", offset_off, default.rod.rod_line(), 3.0, RANGE_OFFSET_M),
        Case("offset-default", default, default.rod.rod_line(), 3.0, RANGE_OFFSET_M),
        Case("curve-off", offset_off, default.rod.rod_line(), 3.0, bias=CURVE),
        Case("curve-offset", offset_only, default.rod.rod_line(), 3.0, bias=CURVE),
        Case("curve-default", default, default.rod.rod_line(), 3.0, bias=CURVE),
    ]


def with_waypoints_file(case: Case, path: Path) -> Case:
    """``case`` with its job visiting ``path`` where the job visits a waypoint file (a case on a
    preset or a design is returned as it is)."""
    if case.job.trajectory.waypoints_file is None:
        return case
    if not path.is_file():
        raise FileNotFoundError(
            f"waypoints file {path} does not exist; give a CSV from `lasercal trajectory design`"
        )
    trajectory = case.job.trajectory.model_copy(update={"waypoints_file": path.resolve()})
    return replace(case, job=case.job.model_copy(update={"trajectory": trajectory}))


@dataclass(frozen=True)
class DesignChoice:
    """How the ``designed-*`` cases' waypoints are laid out: the design's seed, how many
    waypoints and, when given, how many range curve terms it plans for (None:
    ``request_for_job``'s own)."""

    seed: int = 0
    range_terms: int | None = None
    waypoints: int = 20


def designed_waypoints(job: JobConfig, scene: Scene, choice: DesignChoice = DesignChoice()) -> np.ndarray:
    """What ``lasercal trajectory design`` lays out for the scene's scanner (the default 5 cm /
    5 deg uncertainty, a UR5; 20 waypoints and seed 0 unless ``choice`` says otherwise)."""
    mounting = scene.scanner
    T_base_laser = make_transform(
        euler_zyx_to_matrix(*np.radians(mounting.euler_zyx_deg)), mounting.translation_m
    )
    request = request_for_job(job, T_base_laser, UR5, waypoints=choice.waypoints, seed=choice.seed)
    if choice.range_terms is not None:
        request = replace(request, range_terms=choice.range_terms)
    result = design(request, extended_fisher_information)
    return np.array([w.tcp_pose for w in result.waypoints])


def noise_rng(seed: int, stream: int = 0) -> np.random.Generator:
    """The scanner noise of ``seed`` in draw stream ``stream``: stream 0 is
    ``default_rng(seed)``, the benchmarks' own draws; stream K > 0 is seeded from the first draw
    of that generator and K, a stream independent of the others."""
    if stream < 0:
        raise ValueError(f"noise stream {stream} is negative; give 0 (the published draws) or more")
    rng = np.random.default_rng(seed)
    return rng if stream == 0 else np.random.default_rng([int(rng.integers(2**62)), stream])


def seeded_scene(scene: Scene, case: Case, seed: int) -> Scene:
    """The scene of ``seed``: with the bit turned in its chuck by a drawn angle where the case
    asks for it, else ``scene`` itself."""
    return chuck_turned(scene, seed) if case.chuck_turn_drawn else scene


def chuck_turned(scene: Scene, seed: int) -> Scene:
    """``scene`` with its bit turned in its chuck by an angle drawn for ``seed`` (uniform over
    0-180 deg, a two-fluted bit's period)."""
    turn_deg = float(np.random.default_rng(CHUCK_TURN_SEED_BASE + seed).uniform(0.0, 180.0))
    return scene.model_copy(update={"rod": scene.rod.model_copy(update={"chuck_turn_deg": turn_deg})})


def axis_truth(case: Case) -> np.ndarray:
    """The true bit against the job's axis, as ``axis_deviation``: offset (m) at the nominal
    origin and tilt (tangent) along the nominal axis basis."""
    return axis_deviation(case.job.rod.rod_line(), case.true_rod)


def run_case(
    case: Case,
    seeds: int,
    model: str,
    first_seed: int = 0,
    choice: DesignChoice = DesignChoice(),
    noise_stream: int = 0,
    per_waypoint: bool = False,
) -> None:
    """Run one case over ``seeds`` seeds from ``first_seed`` on its scene with the scanner
    ``model``, the scanner noise from ``noise_stream``, and print its distributions (and with
    ``per_waypoint``, each waypoint's centres against the truth)."""
    scene = load_scene(case.scene_path).model_copy(update={"model": model})
    waypoints = designed_waypoints(case.job, scene, choice) if case.designed else job_waypoints(case.job)
    visited = len(waypoints) if case.designed else len(planned_waypoints(case.job))
    scans = round(case.dwell_s / scene.scanner.scan_period_s)
    trials: list[Trial] = []
    centres: list[list[WaypointError]] = []
    failures = 0
    started = time.perf_counter()
    for seed in range(first_seed, first_seed + seeds):
        bias = case.bias or {"bias_offset_m": case.range_offset_m}
        seeded = seeded_scene(scene, case, seed)
        world = world_with(seeded, case.true_rod, ROBOT_ERROR_SEED_BASE + seed, **bias)
        try:
            trials.append(simulate(case.job, waypoints, world, scans, noise_rng(seed, noise_stream)))
        except LasercalError as exc:
            failures += 1
            print(f"  seed {seed}: failed: {exc}")
            continue
        if per_waypoint:
            centres.append(waypoint_errors(trials[-1].observations, world, case.true_rod))
    print(
        f"{case.name} ({model} scanner, noise stream {noise_stream}): {visited} waypoints, "
        f"{scans} scans each, "
        f"{time.perf_counter() - started:.0f} s"
    )
    if not trials:
        return
    found = np.array([t.found for t in trials])
    print(
        f"  found: all {visited} in {int(np.sum(found == visited))} of {len(trials)} runs "
        f"(min {found.min()}, median {np.median(found):.0f}); {failures} runs failed"
    )
    t_err = np.array([np.linalg.norm(t.error_translation_mm) for t in trials])
    r_err = np.array([np.linalg.norm(t.error_rotation_deg) for t in trials])
    for name, values, unit in (("translation", t_err, "mm"), ("rotation", r_err, "deg")):
        p50, p95 = np.percentile(values, [50, 95])
        print(
            f"  {name} error: median {p50:.3f} {unit}, 95th percentile {p95:.3f} {unit}, "
            f"max {values.max():.3f}"
        )
    coverage = np.concatenate(
        [
            np.abs(np.concatenate([t.error_translation_mm, t.error_rotation_deg]))
            / np.concatenate([t.result.std_translation_mm, t.result.std_rotation_deg])
            for t in trials
        ]
    )
    print(
        f"  error components within 2.5 reported std: {np.mean(coverage < 2.5):.1%} "
        f"(worst {coverage.max():.2f})"
    )
    chi_square = np.array([t.result.reduced_chi_square for t in trials])
    print(
        f"  solver reduced chi-square (1 when the centres' stated noise is honest): median "
        f"{np.median(chi_square):.2f}, range {chi_square.min():.2f}-{chi_square.max():.2f}"
    )
    axes = [
        t.result.rod_axis for t in trials if t.result.rod_axis is not None and t.result.rod_axis.estimated
    ]
    if axes:
        print_axis_errors(axes, axis_truth(case))
    offsets = [t.result.range_offset for t in trials if t.result.range_offset is not None]
    if offsets and case.bias:
        print_curve_errors(offsets, case.bias)
    elif offsets and model == "physical":
        counts = np.unique([len(o.terms_mm) for o in offsets], return_counts=True)
        terms = {int(k): int(v) for k, v in zip(*counts, strict=True)}
        print(
            f"  range curve (the physical scanner's own error: no one truth to compare): terms estimated "
            f"{terms}, worst_mm median {np.median([o.worst_mm for o in offsets]):.1f}"
        )
    elif offsets:
        z = np.array([(o.offset_mm - case.range_offset_m * 1e3) / o.std_mm for o in offsets])
        values = np.array([o.offset_mm for o in offsets])
        print(
            f"  range offset: truth {case.range_offset_m * 1e3:.1f} mm, estimated median "
            f"{np.median(values):.2f} mm (std reported {np.median([o.std_mm for o in offsets]):.2f} mm), "
            f"within 2.5 std {np.mean(np.abs(z) < 2.5):.1%}"
        )
    if centres:
        print_waypoint_errors(centres)


def print_curve_errors(offsets: list[RangeOffset], bias: dict[str, float]) -> None:
    """The estimated range error curves against the world's bias, at the curves' own
    distances: the error in mm and in reported std, and how many terms were estimated."""
    misses, z = [], []
    for o in offsets:
        for point in o.curve:
            d = point.distance_m
            truth_mm = 1e3 * (
                bias["bias_offset_m"]
                + bias["bias_per_m"] * d
                + bias["bias_ripple_m"] * np.sin(2.0 * np.pi * d / bias["bias_ripple_period_m"])
            )
            misses.append(point.error_mm - truth_mm)
            z.append((point.error_mm - truth_mm) / point.std_mm)
    terms = [len(o.coefficients_m()) for o in offsets]
    counts = {int(k): int(v) for k, v in zip(*np.unique(terms, return_counts=True), strict=True)}
    worst_mm = np.median([o.worst_mm for o in offsets])
    print(
        f"  range curve: terms estimated {counts}, error against the world's bias RMS "
        f"{np.sqrt(np.mean(np.square(misses))):.2f} mm, within 2.5 std {np.mean(np.abs(z) < 2.5):.1%}; "
        f"worst_mm median {worst_mm:.1f}"
    )


def print_axis_errors(axes: list[RodAxisEstimate], truth: np.ndarray) -> None:
    """The estimated axes against the truth: offset and tilt at the nominal origin, and the
    offset where the rod crossed the plane, in mm / deg and in reported std."""
    offset_mm, tilt_deg = truth[:2] * 1e3, np.degrees(np.arctan(truth[2:]))
    rows = []
    for a in axes:
        crossing_mm = (truth[:2] + a.crossing_along_mm / 1e3 * truth[2:]) * 1e3
        errors = np.concatenate(
            [
                np.asarray(a.offset_mm) - offset_mm,
                np.asarray(a.tilt_deg) - tilt_deg,
                np.asarray(a.crossing_offset_mm) - crossing_mm,
            ]
        )
        stds = np.concatenate([a.offset_std_mm, a.tilt_std_deg, a.crossing_offset_std_mm])
        rows.append((errors, errors / stds))
    errors = np.array([r[0] for r in rows])
    z = np.abs(np.array([r[1] for r in rows]))
    print(
        f"  axis: truth offset {np.round(offset_mm, 2)} mm, tilt {np.round(tilt_deg, 3)} deg; "
        f"estimate off by median {np.median(np.linalg.norm(errors[:, :2], axis=1)):.2f} mm / "
        f"{np.median(np.linalg.norm(errors[:, 2:4], axis=1)):.3f} deg, where it crosses the plane "
        f"{np.median(np.linalg.norm(errors[:, 4:], axis=1)):.2f} mm (reported std there "
        f"{np.median([a.crossing_offset_std_mm for a in axes]):.2f} mm); components within 2.5 std "
        f"{np.mean(z < 2.5):.1%} (worst {z.max():.2f})"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--seeds", type=int, default=5, help="seeds per case (the issue's figures: 20 or more)"
    )
    parser.add_argument("--first-seed", type=int, default=0, help="seed of the first run (default 0)")
    parser.add_argument("--cases", default=None, help="comma-separated case names (default: all)")
    parser.add_argument(
        "--model", choices=("physical", "ideal"), default="physical", help="the scene's scanner model"
    )
    parser.add_argument("--design-seed", type=int, default=0, help="the designed-* cases' design seed")
    parser.add_argument(
        "--design-range-terms",
        type=int,
        choices=range(6),
        default=None,
        help="range curve terms the designed-* cases' design plans for (default: the design's own)",
    )
    parser.add_argument(
        "--design-waypoints", type=int, default=20, help="the designed-* cases' waypoints (default 20)"
    )
    parser.add_argument(
        "--noise-stream",
        type=int,
        default=0,
        help="draw stream of the scanner noise (default 0: the published draws; the worlds unchanged)",
    )
    parser.add_argument(
        "--waypoints-file",
        type=Path,
        default=None,
        help="visit this file in the cases that visit a waypoint file",
    )
    parser.add_argument(
        "--per-waypoint",
        action="store_true",
        help="also each waypoint's centres against the true crossing over the seeds",
    )
    args = parser.parse_args()
    if args.waypoints_file is not None and not args.waypoints_file.is_file():
        parser.error(f"--waypoints-file {args.waypoints_file} does not exist; give a CSV of waypoints")
    if args.noise_stream < 0:
        parser.error(f"--noise-stream {args.noise_stream} is negative; give 0 (the published draws) or more")
    choice = DesignChoice(args.design_seed, args.design_range_terms, args.design_waypoints)
    chosen = cases()
    if args.cases:
        names = set(args.cases.split(","))
        unknown = names - {c.name for c in chosen}
        if unknown:
            parser.error(
                f"unknown case(s) {', '.join(sorted(unknown))}; known: {', '.join(c.name for c in chosen)}"
            )
        chosen = [c for c in chosen if c.name in names]
    if args.waypoints_file is not None:
        chosen = [with_waypoints_file(c, args.waypoints_file) for c in chosen]
    for case in chosen:
        run_case(case, args.seeds, args.model, args.first_seed, choice, args.noise_stream, args.per_waypoint)


if __name__ == "__main__":
    main()
