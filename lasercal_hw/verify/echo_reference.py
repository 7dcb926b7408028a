"""A twist drill's verify compares the middles of the bit's echo, not its fitted centres, across
the bearing.

A twist drill is narrower than the scanner's spot: its segment's flanks are the spot's blur,
and which of them the fit keeps changes from dwell to dwell, moving the fitted centre across the
bearing by 1-2 mm in whole-beam jumps (docs/lab/verify-log.md, ``dwellnoise``). The middle of its echo
strength (``scan.extraction.echo_middle``) moves continuously: fluted drill job, seed 100, 33
waypoints, 6 dwells each, across scatter median 0.03 mm against 0.55 mm for the fitted centres.
It lies off the axis by the section's glint, by the same at every dwell of a pose (the bit's turn
repeats there), so the calibration records it (``WaypointResidual.echo_middle_uv_mm``) and the
verify compares its own with that: not the axis, but its change.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from lasercal_hw.models import FloatArray
from lasercal_hw.run.records import WaypointMeasurement
from lasercal_hw.run.two_pass import SecondPassRefit
from lasercal_hw.scan.average import AveragedScan

#: Draws of a dwell's averaged intensities (each within its std) that tell whether the bit's
#: echo middle can jump, and the seed they are drawn with (a verify repeats its own figures).
JUMP_DRAWS = 40
JUMP_SEED = 0


def at_echo_middles(
    refit: SecondPassRefit,
    measured: Sequence[WaypointMeasurement],
    predicted: FloatArray,
    recorded: FloatArray,
    reference: FloatArray,
    noise: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The verify's centres (N, 2), references (the calibration's residuals, N, 2) and dwell
    noise (N, 2, 2) with, at each waypoint whose echo middle both the calibration recorded
    (``recorded``: N rows of ``recorded_echo_middles``) and this dwell shows, both turned about
    the scanner onto their middle's bearing, and the noise across the bearing the middle's (its
    levels' scatter or, where wider, how far draws of the dwell's intensities move it: ``_jump_m2``).
    Elsewhere as they were. This dwell's middle is looked for from where the calibration looked
    for its own, the calibration's centre: ``predicted`` (N, 2, the crossings as the drift test
    predicts them, ``verify.drift.predictions``) plus its residual. Not about this dwell's
    centre: a fit that kept another part of the segment (fluted drill job, seed 105: 8.5 mm
    aside) would look beside the bit's echo. Nor about the calibration's middle, or a crossing
    predicted otherwise (``predict_rod``, without the range curve): the search's window and
    brightest beam move with where it starts, and the calibration's own scans then read another
    middle, or none (seed 100, waypoint 30: 1.4 mm; seed 105, waypoint 37: none, 5.5 mm off)."""
    centres = np.array([m.centre.centre_uv_m for m in measured], dtype=float)
    reference, noise = np.array(reference, dtype=float), np.array(noise, dtype=float)
    for k, m in enumerate(measured):
        if not (np.isfinite(recorded[k]).all() and np.isfinite(reference[k]).all()):
            continue  # no middle recorded here: a plain rod, no intensities, or none found
        origin = predicted[k] + reference[k]
        middle = refit.echo_middle(m.averaged, m.tcp_pose, origin)
        if middle is None:
            continue
        jump_m2 = _jump_m2(refit, m.averaged, m.tcp_pose, origin)
        middle = replace(middle, noise_m2=max(middle.noise_m2, jump_m2))
        along = np.outer(centres[k], centres[k]) / float(centres[k] @ centres[k])
        noise[k] = along @ noise[k] @ along + middle.noise_uv_m2(centres[k])
        centres[k] = middle.turned_onto(centres[k])
        reference[k] = reference[k] + recorded[k, :2]
    return centres, reference, noise


def _jump_m2(
    refit: SecondPassRefit, averaged: AveragedScan, tcp_pose: FloatArray, origin: FloatArray
) -> float:
    """The variance of the echo middle's place across the bearing (m^2) over ``JUMP_DRAWS``
    draws of the dwell's averaged intensities within their std: a bit's middle that sits in one
    of two places by a hair of the intensities shows both here. Fluted drill job, seed 249,
    waypoint 12: over 30 dwells the middle read 1.53-1.70 mm across at 26 and 0.27-0.33 mm at 4
    (the calibration's among them: a false alarm, chi-square 90); these draws on every one of
    five dwells spread 0.20-1.77 mm (std 0.32-0.68 mm), where the levels' scatter said far less.
    0 without intensity stds."""
    if averaged.intensities is None or averaged.intensity_std is None:
        return 0.0
    rng = np.random.default_rng(JUMP_SEED)
    spread = np.nan_to_num(averaged.intensity_std)
    shifts = []
    for _ in range(JUMP_DRAWS):
        drawn = replace(averaged, intensities=averaged.intensities + rng.normal(size=spread.size) * spread)
        middle = refit.echo_middle(drawn, tcp_pose, origin)
        if middle is not None:
            shifts.append(middle.shift_m)
    return float(np.var(shifts)) if len(shifts) > 1 else 0.0
