"""Measure a real Hokuyo's noise, intensity and edge behaviour on public logs, beside the model.

    .venv/bin/python -m benchmarks.scanner_data --ubh LOG.ubh [--ubh MORE.ubh] [--flat-csv RAW.csv]

``--ubh``: an UrgBenri log (``[scan]`` lines of ``range;range;...`` or, in ME mode,
``range|intensity;...``; the public UTM-30LX-EW logs of ``finalobject/HumanDetectingOnLidar``
under ``flies/data/June_1/``).  Static beams (reading spread under 30 mm over the log) give
the per-reading noise by range and by intensity, the intensity by range and (steadier
beams) the intensity's own reading-to-reading scatter; the median
scan's depth edges give the mixed-pixel ramps; adjacent steps that repeat the same reading
are counted.  ``--flat-csv``: ``actual_distance_m,sample_1,...`` rows of a flat target
(``jackfruittt/Hokuyo_Calibration``, ``lidar_calibration_raw.csv``): bias and spread by
distance.  Each figure is printed beside what the physical model (``fakes/scanner_model``,
default parameters) gives for it; docs/scanner-model.md cites the results.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from fakes.scanner_model.materials import backscatter
from fakes.scanner_model.physical import intensity_for, receiver_overlap
from fakes.scanner_model.range_error import range_bias_m, range_sigma_m
from fakes.scene import PhysicsSettings
from lasercal_hw.models import FloatArray

STATIC_SPREAD_M = 0.030
STEADY_SPREAD_M = 0.005
EDGE_JUMP_M = 0.15
PLATEAU_M = 0.015
MIN_VALID_MM = 23


def read_ubh(path: Path) -> tuple[FloatArray, FloatArray | None]:
    """Ranges (scans, steps; NaN for error codes) and intensities (or None) of a log."""
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    ranges, intensities = [], []
    for index, line in enumerate(lines[:-1]):
        if line.strip() != "[scan]":
            continue
        values = [v for v in lines[index + 1].strip().split(";") if v]
        pairs = [v.split("|") for v in values]
        ranges.append([int(p[0]) for p in pairs])
        if len(pairs[0]) > 1:
            intensities.append([int(p[1]) for p in pairs])
    if not ranges:
        raise SystemExit(f"{path}: no [scan] lines; is this an UrgBenri .ubh log?")
    mm = np.array(ranges, dtype=float)
    metres = np.where(mm >= MIN_VALID_MM, mm / 1000.0, np.nan)
    return metres, (np.array(intensities, dtype=float) if intensities else None)


def noise_and_intensity(ranges: FloatArray, intensities: FloatArray | None, physics: PhysicsSettings) -> None:
    """Per-reading spread of static beams by range and by intensity; intensity by range."""
    with np.errstate(invalid="ignore"):
        median = np.nanmedian(ranges, axis=0)
        spread = np.nanstd(ranges, axis=0)
    static = np.isfinite(median) & (spread < STATIC_SPREAD_M) & (np.isfinite(ranges).mean(axis=0) > 0.9)
    print(f"  {ranges.shape[0]} scans, {static.sum()} static beams")
    print("  range bin     beams  reading std (data)  intensity median (data)  model: painted intensity, std")
    level = None if intensities is None else np.nanmedian(intensities, axis=0)
    for low in np.arange(0.0, 3.0, 0.1):
        beams = static & (median >= low) & (median < low + 0.1)
        if beams.sum() < 5:
            continue
        middle = low + 0.05
        model_i = intensity_for(
            physics,
            backscatter("painted", np.ones(1)) * receiver_overlap(np.array([middle]), physics) / middle**2,
        )
        text = "" if level is None else f"{np.median(level[beams]):10.0f}"
        print(
            f"  {low:.1f}-{low + 0.1:.1f} m  {beams.sum():6d}  {1000 * np.median(spread[beams]):9.1f} mm"
            f"  {text:>22}   {model_i[0]:8.0f}, {1000 * range_sigma_m(model_i, physics)[0]:.1f} mm"
        )
    if level is None:
        return
    print("  intensity bin     beams  reading std (data)  model std")
    for low, high in ((0, 2000), (2000, 3000), (3000, 4000), (4000, 5000), (5000, 6000), (6000, 13000)):
        beams = static & (level >= low) & (level < high)
        if beams.sum() < 5:
            continue
        model = range_sigma_m(np.array([0.5 * (low + high)]), physics)[0]
        print(
            f"  {low:5d}-{high:<5d}  {beams.sum():6d}  {1000 * np.median(spread[beams]):9.1f} mm"
            f"  {1000 * model:8.1f} mm"
        )


def intensity_scatter(ranges: FloatArray, intensities: FloatArray, physics: PhysicsSettings) -> None:
    """Reading-to-reading intensity scatter (std over mean across scans) of steady beams (range
    spread under ``STEADY_SPREAD_M``, valid in nearly every scan), by intensity, beside the model's."""
    with np.errstate(invalid="ignore"):
        spread = np.nanstd(ranges, axis=0)
    steady = (spread < STEADY_SPREAD_M) & (np.isfinite(ranges).mean(axis=0) > 0.98)
    readings = np.where(np.isfinite(ranges), intensities, np.nan)
    with np.errstate(invalid="ignore"):
        mean = np.nanmean(readings, axis=0)
        scatter = np.nanstd(readings, axis=0, ddof=1) / mean
    print(
        f"  intensity scatter of {steady.sum()} steady beams (range std < {1000 * STEADY_SPREAD_M:.0f} mm): "
        f"median {100 * np.median(scatter[steady]):.2f} %, 10-90 % "
        f"{100 * np.percentile(scatter[steady], 10):.2f}-{100 * np.percentile(scatter[steady], 90):.2f} %; "
        f"model {100 * physics.intensity_noise:.2f} % (`intensity_noise`: a beam wholly on one surface)"
    )
    for low, high in ((0, 2000), (2000, 3000), (3000, 5000), (5000, 13000)):
        beams = steady & (mean >= low) & (mean < high)
        if beams.sum() >= 5:
            median = 100 * np.median(scatter[beams])
            print(f"    intensity {low:5d}-{high:<5d}  {beams.sum():4d} beams  median {median:.2f} %")


def edges_and_repeats(ranges: FloatArray, intensities: FloatArray | None) -> None:
    """Ramp lengths at depth edges of the median scan; repeated adjacent readings."""
    with np.errstate(invalid="ignore"):
        median = np.nanmedian(ranges, axis=0)
        spread = np.nanstd(ranges, axis=0)
    ramps, unstable = [], []
    k = 0
    while k < median.size - 2:
        if (
            not (np.isfinite(median[k]) and np.isfinite(median[k + 1]))
            or abs(median[k + 1] - median[k]) < PLATEAU_M
        ):
            k += 1
            continue
        start = k  # last beam of the plateau before the edge
        end = k + 1
        while (
            end < median.size - 1
            and np.isfinite(median[end + 1])
            and abs(median[end + 1] - median[end]) >= PLATEAU_M
        ):
            end += 1
        # ``end`` is the first beam of the next plateau.
        if abs(median[end] - median[start]) >= EDGE_JUMP_M and end - start <= 20:
            inner = np.arange(start + 1, end)
            between = inner[
                (np.minimum(median[start], median[end]) + PLATEAU_M < median[inner])
                & (median[inner] < np.maximum(median[start], median[end]) - PLATEAU_M)
            ]
            ramps.append(between.size)
            unstable.extend(spread[between].tolist())
        k = end
    if ramps:
        counts = np.bincount(ramps)
        print(
            f"  depth edges (> {EDGE_JUMP_M * 1000:.0f} mm): {len(ramps)}; beams between the two sides: "
            + ", ".join(f"{n}: {c}" for n, c in enumerate(counts) if c)
        )
        if unstable:
            print(
                f"  reading std of those mixed beams: median {1000 * np.median(unstable):.1f} mm, "
                f"{np.mean(np.asarray(unstable) < 0.010) * 100:.0f} % under 10 mm (steady)"
            )
    same = (ranges[:, 1:] == ranges[:, :-1]) & np.isfinite(ranges[:, 1:])
    if intensities is not None:
        same &= intensities[:, 1:] == intensities[:, :-1]
    print(
        "  adjacent steps repeating the same reading"
        f"{' (range and intensity)' if intensities is not None else ''}: {100 * same.mean():.1f} %"
    )


def flat_target(path: Path, physics: PhysicsSettings) -> None:
    """Bias and spread per distance of ``actual_distance_m,sample_1,...`` rows."""
    data = np.genfromtxt(path, delimiter=",", skip_header=1)
    data = np.atleast_2d(data)
    print("  distance   bias (data)  std (data)   model bias (intensity 2500)")
    for row in data:
        truth, samples = row[0], row[1:][np.isfinite(row[1:])]
        model = range_bias_m(np.array([truth]), np.array([2500.0]), physics)[0]
        print(
            f"  {truth:.3f} m  {1000 * (samples.mean() - truth):+8.1f} mm"
            f"  {1000 * samples.std(ddof=1):7.1f} mm   {1000 * model:+8.1f} mm"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ubh", type=Path, action="append", default=[], help="UrgBenri log (repeatable)")
    parser.add_argument("--flat-csv", type=Path, help="flat-target samples: actual_distance_m,sample_1,...")
    args = parser.parse_args(argv)
    if not args.ubh and args.flat_csv is None:
        parser.error("give at least one --ubh log or a --flat-csv file")
    physics = PhysicsSettings()
    for path in args.ubh:
        if not path.is_file():
            parser.error(f"{path}: no such file")
        print(f"{path.name}:")
        ranges, intensities = read_ubh(path)
        noise_and_intensity(ranges, intensities, physics)
        if intensities is not None:
            intensity_scatter(ranges, intensities, physics)
        edges_and_repeats(ranges, intensities)
    if args.flat_csv is not None:
        if not args.flat_csv.is_file():
            parser.error(f"{args.flat_csv}: no such file")
        print(f"{args.flat_csv.name}:")
        flat_target(args.flat_csv, physics)
    return 0


if __name__ == "__main__":
    sys.exit(main())
