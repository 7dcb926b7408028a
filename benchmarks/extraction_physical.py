"""Rod extraction on the physical scanner model, beside the ideal model in the same run.

    .venv/bin/python -m benchmarks.extraction_physical [--seeds 1] [--first-seed 0] [--scans 40]
        [--quick] [--misses] [--sideways]

Rods of radius 4 mm (a twist drill and cylinders), 10, 20 and 45 mm, of every material,
0.1 to 3 m from the scanner at random bearings, with a wall 0.3 m (near) or 2.5 m (far)
behind; each a dwell of ``--scans`` scans plus a background dwell, averaged and passed to
``find_rod_centre`` with the background and the (vertical) axis, as a second pass does.

Judged are the positions where at least 5 beams hit the rod (issue 18).  A beam hits it when
its centre ray meets the rod *and* the scanner's noise-free reading there is the rod's own
(within half a radius, at least 5 mm, of the rod's surface after the model's range error):
a rod narrower than the beam's spot in front of a near wall gives only blends of the two,
and a dark rod far away no echo at all; such positions are *skipped*, with the reason, and
any centre returned there is still checked.  Each centre is judged after the scanner's
range-error curve is removed, as a calibration removes it: the model's own curve for this
rod (``front_range_error_m``: its front beam's true range and noise-free
intensity through the model's bias), moved along the bearing as the solver's curve moves
it; the solver's estimated curve (one to three terms) leaves some of it, not judged here.

A last row, apart from the table (its own bearings): a polished 10 mm steel rod at
0.4-0.6 m before a wall 0.9-1.2 m behind (three bearings each), a pulse length, where the
wall's echo no longer merges with the rod's but its pulse still pulls the rod's echo long (the
drill job's floor).  Another, also apart: rods before a background that is not square to the
bearing (``UNEVEN_*``; the dry run's waypoint 18), different beside the rod's two edges;
``--sideways`` prints each of its positions' sideways error against the reported sideways std.

Per rod and material, and per range: the positions judged, how many were found, the
fraction of error components within 2.5 reported std (90-99 % when the covariance is
honest), how many centres lie more than 3 reported std from the truth without a warning
(``RodCentre.warnings``; skipped positions included), how many centres carry a warning and
how many of those are more than 3 std off (a warning must be earned: one on every good centre
teaches users to ignore it), the median error, and the skipped positions.  The ideal
model's figures for the same positions are the reference (issue 18 asks for >= 99 % found,
no silent > 3 std centre, 90-99 % within 2.5 std); under the ``all`` row, how often a
covariance exactly right for gaussian errors would meet those two on as many centres
(``honest_odds``).  ``--misses``
prints every judged position not found and every silent > 3 std centre, with the reason.
``--first-seed`` picks other seeds and bearings: tune on those, report the default.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from fakes.scanner_model.dwell import Segment, SimulatedDwell, oblique_wall, simulate_dwell, step_behind_edge
from lasercal_hw.errors import CalibrationError
from lasercal_hw.scan.average import average_scans
from lasercal_hw.scan.extraction import find_rod_centre
from tests.physical_truth import front_range_error_m

RANGES_M = (0.1, 0.15, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0)
BACKGROUNDS_M = {"near": 0.3, "far": 2.5}
MATERIALS = ("matte", "painted", "bare_metal", "steel_drill", "retro_tape", "dark")
RODS = (  # (label, radius, shape, materials)
    ("drill 4 mm", 0.004, "twist_drill", ("steel_drill",)),
    ("rod 4 mm", 0.004, "cylinder", MATERIALS),
    ("rod 10 mm", 0.010, "cylinder", MATERIALS),
    ("rod 20 mm", 0.020, "cylinder", MATERIALS),
    ("rod 45 mm", 0.045, "cylinder", MATERIALS),
)
MIN_BEAMS = 5
WITHIN_STD = 2.5
OFF_STD = 3.0
#: The share of error components within ``WITHIN_STD`` that issue 18 asks for.
BAND = (0.90, 0.99)
#: True std over reported std, for ``print_honest_odds``' best case.
HONEST_RATIOS = (0.8, 0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15, 1.2)
BEAM_STEP_RAD = 2.0 * np.pi / 1440
#: A pulse length behind: a polished 10 mm rod (the drill job's bit) before a wall just beyond
#: the echo merge (0.85 m), whose lobe still pulls the rod's echo peak long (docs/extraction.md).
PULSE_RANGES_M = (0.4, 0.5, 0.6)
PULSE_BACKGROUNDS_M = (0.9, 1.0, 1.1, 1.2)
PULSE_ROD = ("rod 5 mm", 0.005, "cylinder", "steel_drill")
PULSE_BEARINGS = 3
MIN_OWN_TOLERANCE_M = 0.005
#: A background not square to the bearing, so different beside the rod's two edges (the dry
#: run's waypoint 18: docs/lab/extraction-log.md, "Why the dry run got worse"): the dry run's 20 mm
#: painted rod and a 10 mm steel rod at 0.3-0.6 m before a wall seen 20-35 deg from its normal
#: 1.5-2.5 m behind ("oblique"), or before a step ("step"): a near wall 0.5-1 m behind, its edge
#: on the ray past one edge of the rod, running away from the rod, and a far wall 2 m behind.
UNEVEN_RODS = (("rod 20 mm", 0.020, "painted"), ("rod 10 mm", 0.010, "steel_drill"))
UNEVEN_RANGES_M = (0.3, 0.4, 0.5, 0.6)
UNEVEN_KINDS = ("oblique", "step")
UNEVEN_BEARINGS = 3
OBLIQUE_TURN_DEG = (20.0, 35.0)
OBLIQUE_BEHIND_M = (1.5, 2.5)
STEP_NEAR_BEHIND_M = (0.5, 1.0)
STEP_FAR_BEHIND_M = 2.0


@dataclass(frozen=True)
class Outcome:
    """One extraction: error (m, range error removed), covariance, warned, the beams reading
    the rod's own echo, the refusal's reason (None when found) and how long
    ``find_rod_centre`` took (s)."""

    error_m: np.ndarray | None
    covariance: np.ndarray | None
    warned: bool
    own_beams: int
    reason: str | None
    seconds: float = 0.0

    def whitened(self) -> np.ndarray:
        """The error in units of the reported covariance's Cholesky factor (inf where that
        covariance is not positive definite); needs a found centre."""
        try:
            return np.linalg.solve(np.linalg.cholesky(self.covariance), self.error_m)
        except np.linalg.LinAlgError:
            return np.full(2, np.inf)


@dataclass
class Tally:
    """Outcomes of the positions where at least ``MIN_BEAMS`` beams hit the rod."""

    positions: int = 0
    found: int = 0
    skipped: int = 0
    components: list[float] = field(default_factory=list)
    silent_off: int = 0
    warned: int = 0
    warned_off: int = 0
    errors_mm: list[float] = field(default_factory=list)

    def add(self, outcome: Outcome) -> bool:
        """Count one outcome; True when it is a miss or a silent wrong centre."""
        judged = outcome.own_beams >= MIN_BEAMS
        self.positions += judged
        self.skipped += not judged
        if outcome.error_m is None or outcome.covariance is None:
            return judged
        whitened = outcome.whitened()
        off = float(np.linalg.norm(whitened)) > OFF_STD
        silent = off and not outcome.warned
        self.silent_off += silent
        self.warned += outcome.warned
        self.warned_off += off and outcome.warned
        if judged:
            self.found += 1
            self.errors_mm.append(1000.0 * float(np.linalg.norm(outcome.error_m)))
            self.components.extend(np.abs(whitened).tolist())
        return silent

    def merge(self, other: Tally) -> None:
        self.positions += other.positions
        self.found += other.found
        self.skipped += other.skipped
        self.components += other.components
        self.silent_off += other.silent_off
        self.warned += other.warned
        self.warned_off += other.warned_off
        self.errors_mm += other.errors_mm

    def row(self) -> str:
        if not self.positions and not self.skipped:
            return "      -"
        found = 100 * self.found / self.positions if self.positions else float("nan")
        within = np.mean(np.asarray(self.components) <= WITHIN_STD) if self.components else float("nan")
        median = np.median(self.errors_mm) if self.errors_mm else float("nan")
        return (
            f"{self.found:4d}/{self.positions:<4d} {found:5.1f} %  {100 * within:5.1f} %  "
            f"{self.silent_off:4d}  {self.warned:3d} ({self.warned_off:3d})  "
            f"{median:7.2f} mm  {self.skipped:3d}"
        )


def honest_odds(
    centres: int, ratio: float = 1.0, trials: int = 20000, seed: int = 0
) -> tuple[float, float, float]:
    """How often errors drawn from a gaussian of ``ratio`` times the reported covariance, on
    ``centres`` 2-D centres none of which warns, meet the band (``BAND`` of components within
    ``WITHIN_STD``), have no centre more than ``OFF_STD`` off, and both: what a covariance that is
    exactly right (``ratio`` 1) would score on the benchmark's criteria (Monte Carlo)."""
    rng = np.random.default_rng(seed)
    band = silent_free = both = 0
    for chunk in np.array_split(np.arange(trials), max(1, trials * centres // 1_000_000)):
        whitened = ratio * rng.standard_normal((chunk.size, centres, 2))
        within = np.mean(np.abs(whitened) <= WITHIN_STD, axis=(1, 2))
        in_band = (within >= BAND[0]) & (within <= BAND[1])
        none_off = np.all(np.linalg.norm(whitened, axis=2) <= OFF_STD, axis=1)
        band += int(in_band.sum())
        silent_free += int(none_off.sum())
        both += int((in_band & none_off).sum())
    return band / trials, silent_free / trials, both / trials


def beams_on_rod(range_m: float, radius_m: float) -> int:
    """Beams whose centre ray meets a rod of ``radius_m`` at ``range_m`` (0.25 deg steps)."""
    return int(2 * np.floor(np.arcsin(min(radius_m / range_m, 1.0)) / BEAM_STEP_RAD) + 1)


def own_echo_beams(dwell: SimulatedDwell) -> int:
    """How many beams' noise-free readings are the rod's own echo (after the model's range
    error at the rod)."""
    angles = dwell.world.angles_rad
    directions = np.column_stack([np.cos(angles), np.sin(angles)])
    along = directions @ dwell.centre_uv_m
    miss = np.abs(directions[:, 0] * dwell.centre_uv_m[1] - directions[:, 1] * dwell.centre_uv_m[0])
    hits = (miss < dwell.radius_m) & (along > 0.0)
    surface_m = along - np.sqrt(np.fmax(dwell.radius_m**2 - miss**2, 0.0))
    raw_mm, _ = dwell.world.scan_mm(dwell.T_base_tcp)
    reading_m = np.where(raw_mm > 20, raw_mm / 1000.0, np.inf)
    bias_m = front_range_error_m(dwell)
    tolerance = max(0.5 * dwell.radius_m, MIN_OWN_TOLERANCE_M)
    own = hits & (np.abs(reading_m - surface_m - bias_m) <= tolerance)
    return int(own.sum())


def reason_kind(reason: str | None) -> str:
    """A refusal's first sentence with its figures left out (to count refusals by kind)."""
    if reason is None:
        return "a centre was returned (judged only for > 3 std without a warning)"
    return re.sub(r"[-+]?\d+(\.\d+)?", "#", reason.split(";")[0].split(":")[0])[:100]


def measure(
    model: str,
    radius_m: float,
    shape: str,
    material: str,
    range_m: float,
    background_m: float | None,
    bearing_rad: float,
    seed: int,
    scans: int,
    walls: Sequence[Segment] = (),
) -> Outcome:
    """One extraction against the truth, with the model's range error at the rod removed;
    ``walls``: more background (``simulate_dwell``'s)."""
    centre = range_m * np.array([np.cos(bearing_rad), np.sin(bearing_rad)])
    dwell = simulate_dwell(
        centre,
        radius_m,
        material=material,  # type: ignore[arg-type]
        shape=shape,
        background_m=background_m,
        walls=walls,
        scan_count=scans,
        background_count=scans,
        seed=seed,
        model=model,  # type: ignore[arg-type]
        spindle_deg=float(np.degrees(bearing_rad) * 7.0),
    )
    own, bias_m = own_echo_beams(dwell), front_range_error_m(dwell)
    scan, background = average_scans(dwell.scans), average_scans(dwell.background)
    start = time.perf_counter()
    try:
        result = find_rod_centre(
            scan,
            radius_m=radius_m,
            background=background,
            axis_in_scanner=np.array([0.0, 0.0, 1.0]),
            fluted=shape == "twist_drill",
        )
    except CalibrationError as exc:
        return Outcome(None, None, False, own, str(exc), time.perf_counter() - start)
    seconds = time.perf_counter() - start
    bearing = centre / np.linalg.norm(centre)
    error = result.centre_uv_m - bias_m * bearing - dwell.centre_uv_m
    return Outcome(error, result.covariance_uv_m2, bool(result.warnings), own, None, seconds)


def pulse_length_behind(first_seed: int, seeds: int, scans: int, misses: bool) -> dict[str, Tally]:
    """The polished rod a pulse length before a wall (``PULSE_*``), per model; with ``misses``
    every miss and silent wrong centre printed."""
    label, radius_m, shape, material = PULSE_ROD
    tallies = {model: Tally() for model in ("physical", "ideal")}
    rng = np.random.default_rng(1800 + first_seed)
    for range_m in PULSE_RANGES_M:
        for background_m in PULSE_BACKGROUNDS_M:
            for seed in range(first_seed, first_seed + seeds):
                for bearing in rng.uniform(-1.2, 1.2, PULSE_BEARINGS):
                    for model in tallies:
                        outcome = measure(
                            model, radius_m, shape, material, range_m, background_m, bearing, seed, scans
                        )
                        if tallies[model].add(outcome) and misses:
                            what = outcome.reason or f"error {1000 * outcome.error_m} mm"  # type: ignore[operator]
                            print(
                                f"{model:8s} {label} {material} {range_m} m, wall {background_m} m behind, "
                                f"bearing {bearing:+.3f} rad, seed {seed}, {outcome.own_beams} own beams: "
                                f"{what}"
                            )
    return tallies


def uneven_walls(
    kind: str, range_m: float, radius_m: float, bearing_rad: float, rng: np.random.Generator
) -> tuple[list[Segment], str]:
    """The walls of an uneven background of ``kind`` (``UNEVEN_KINDS``) behind a rod at
    ``range_m`` and ``bearing_rad``, drawn from ``rng``, and what they are in words."""
    centre = range_m * np.array([np.cos(bearing_rad), np.sin(bearing_rad)])
    side = int(rng.choice((-1, 1)))
    if kind == "oblique":
        turn_deg = side * float(rng.uniform(*OBLIQUE_TURN_DEG))
        behind_m = float(rng.uniform(*OBLIQUE_BEHIND_M))
        return oblique_wall(centre, behind_m, turn_deg), f"wall {behind_m:.2f} m behind, {turn_deg:+3.0f} deg"
    behind_m = float(rng.uniform(*STEP_NEAR_BEHIND_M))
    walls = step_behind_edge(centre, radius_m, side, behind_m, STEP_FAR_BEHIND_M)
    return walls, f"step {behind_m:.2f} / {STEP_FAR_BEHIND_M:.2f} m behind, near on {side:+d}"


def sideways_line(outcome: Outcome, bearing_rad: float) -> str:
    """An outcome's error across the bearing against its reported std there, its whole error
    in reported std, and whether it warned (or, > 3 std without, is silent)."""
    if outcome.error_m is None or outcome.covariance is None:
        return f"not found ({outcome.own_beams} own beams): {outcome.reason}"
    across = np.array([-np.sin(bearing_rad), np.cos(bearing_rad)])
    error_m = float(across @ outcome.error_m)
    std_m = float(np.sqrt(across @ outcome.covariance @ across))
    off = float(np.linalg.norm(outcome.whitened()))
    flag = "warned" if outcome.warned else ("SILENT" if off > OFF_STD else "")
    return (
        f"{1000 * error_m:+6.2f} mm across, std {1000 * std_m:5.2f} mm ({error_m / std_m:+5.1f}), "
        f"{off:4.1f} std in all {flag:6s}"
    )


def uneven_background(first_seed: int, seeds: int, scans: int, sideways: bool) -> dict[str, Tally]:
    """The rods before an uneven background (``UNEVEN_*``), per model; with ``sideways`` every
    position's sideways error printed for both models."""
    tallies = {model: Tally() for model in ("physical", "ideal")}
    rng = np.random.default_rng(1900 + first_seed)
    for label, radius_m, material in UNEVEN_RODS:
        for range_m in UNEVEN_RANGES_M:
            for kind in UNEVEN_KINDS:
                for seed in range(first_seed, first_seed + seeds):
                    for _ in range(UNEVEN_BEARINGS):
                        bearing = float(rng.uniform(-1.2, 1.2))
                        walls, where = uneven_walls(kind, range_m, radius_m, bearing, rng)
                        lines = []
                        for model, tally in tallies.items():
                            outcome = measure(
                                model, radius_m, "cylinder", material, range_m, None, bearing, seed, scans,
                                walls,
                            )
                            tally.add(outcome)
                            lines.append(f"{model} {sideways_line(outcome, bearing)}")
                        if sideways:
                            print(
                                f"{label} {material:11s} {range_m} m, {where}, bearing {bearing:+.3f} rad, "
                                f"seed {seed}: {' | '.join(lines)}"
                            )
    return tallies


def print_honest_odds(centres: int) -> None:
    """What an exactly right covariance would score on ``centres`` centres (``honest_odds``):
    the band and "no silent centre" together are met only by errors lighter-tailed than a
    gaussian (docs/extraction.md, "Why the band and no silent centre pull apart")."""
    if not centres:
        return
    odds = {ratio: honest_odds(centres, ratio) for ratio in HONEST_RATIOS}
    band, silent_free, both = odds[1.0]
    best_both, best_ratio = max((both_met, ratio) for ratio, (_, _, both_met) in odds.items())
    print(
        f"for reference, gaussian errors with exactly the reported covariance on {centres} centres "
        f"(none warned): in the band {100 * band:.1f} % of the time, no centre > {OFF_STD:g} std "
        f"{100 * silent_free:.1f} %, both {100 * both:.1f} %; both at best {100 * best_both:.1f} % "
        f"(true std {best_ratio:g} x the reported)"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1, help="random bearings per position (default 1)")
    parser.add_argument(
        "--first-seed", type=int, default=0,
        help="first seed and bearing set (default 0; tune on others, e.g. 100, and report 0)",
    )
    parser.add_argument("--scans", type=int, default=40, help="scans per dwell (default 40, 1 s)")
    parser.add_argument("--quick", action="store_true", help="every other range, near background only")
    parser.add_argument("--misses", action="store_true", help="print every miss and silent wrong centre")
    parser.add_argument(
        "--sideways", action="store_true",
        help="print every uneven-background position's sideways error against its reported std",
    )
    args = parser.parse_args(argv)
    ranges = RANGES_M[::2] if args.quick else RANGES_M
    backgrounds = {"near": BACKGROUNDS_M["near"]} if args.quick else BACKGROUNDS_M
    by_rod: dict[tuple[str, str, str], Tally] = defaultdict(Tally)
    by_range: dict[tuple[str, float], Tally] = defaultdict(Tally)
    skip_reasons: dict[str, int] = defaultdict(int)
    seconds: dict[str, list[float]] = defaultdict(list)
    rng = np.random.default_rng(18 + args.first_seed)
    for label, radius_m, shape, materials in RODS:
        for material in materials:
            for range_m in ranges:
                if beams_on_rod(range_m, radius_m) < MIN_BEAMS:
                    continue
                for background_name, background_m in backgrounds.items():
                    for seed in range(args.first_seed, args.first_seed + args.seeds):
                        bearing = float(rng.uniform(-1.2, 1.2))
                        for model in ("physical", "ideal"):
                            outcome = measure(
                                model, radius_m, shape, material, range_m, background_m, bearing, seed,
                                args.scans,
                            )
                            notable = by_rod[(model, label, material)].add(outcome)
                            seconds[model].append(outcome.seconds)
                            by_range[(model, range_m)].add(outcome)
                            if model == "physical" and outcome.own_beams < MIN_BEAMS:
                                skip_reasons[reason_kind(outcome.reason)] += 1
                            if args.misses and notable:
                                what = outcome.reason or f"error {1000 * outcome.error_m} mm"  # type: ignore[operator]
                                print(
                                    f"{model:8s} {label} {material} {range_m} m, {background_name} wall, "
                                    f"bearing {bearing:+.3f} rad, seed {seed}, "
                                    f"{outcome.own_beams} own beams: {what}"
                                )
    header = "  found            within 2.5 std  >3 std silent  warned (off)  median error  skipped"
    print(
        f"positions with >= {MIN_BEAMS} beams on the rod; {args.scans} scans per dwell; "
        f"backgrounds {', '.join(f'{k} {v} m' for k, v in backgrounds.items())}; {args.seeds} seed(s); "
        "error after the model's range-error curve at the rod is removed"
    )
    print(f"{'rod':12s} {'material':12s} {'physical model':>46s}        | ideal model (reference)")
    print(f"{'':25s}{header}")
    for label, _, _, materials in RODS:
        for material in materials:
            physical, ideal = by_rod[("physical", label, material)], by_rod[("ideal", label, material)]
            print(f"{label:12s} {material:12s} {physical.row()}   | {ideal.row()}")
    print("\nby range (all rods and materials):")
    for range_m in ranges:
        physical, ideal = by_range[("physical", range_m)], by_range[("ideal", range_m)]
        print(f"{range_m:5.2f} m {'':19s}{physical.row()}   | {ideal.row()}")
    total = {m: Tally() for m in ("physical", "ideal")}
    for (model, _, _), tally in by_rod.items():
        total[model].merge(tally)
    print(f"\n{'all':32s}{total['physical'].row()}   | {total['ideal'].row()}")
    print_honest_odds(total["physical"].found)
    pulse = pulse_length_behind(args.first_seed, args.seeds, args.scans, args.misses)
    print(
        f"{'polished 10 mm, wall 0.9-1.2 m':32s}{pulse['physical'].row()}   | {pulse['ideal'].row()}"
    )
    uneven = uneven_background(args.first_seed, args.seeds, args.scans, args.sideways)
    print(
        f"{'uneven background, 0.3-0.6 m':32s}{uneven['physical'].row()}   | {uneven['ideal'].row()}"
    )
    print(
        "find_rod_centre per dwell (median / 95th percentile): "
        + ", ".join(
            f"{model} {1000 * np.median(times):.0f} / {1000 * np.percentile(times, 95):.0f} ms"
            for model, times in seconds.items()
        )
    )
    print("\nskipped positions (fewer than 5 beams read the rod's own echo), physical model, by outcome:")
    for reason, count in sorted(skip_reasons.items(), key=lambda item: -item[1]):
        print(f"  {count:4d}  {reason}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
