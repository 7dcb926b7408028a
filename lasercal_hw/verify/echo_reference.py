"""A twist drill's verify compares the middles of the bit's echo, not its fitted centres, across
the bearing.

A twist drill is narrower than the scanner's spot: its segment's flanks are the spot's blur,
and which of them the fit keeps changes from dwell to dwell, moving the fitted centre across the
bearing by 1-2 mm in whole-beam jumps (docs/verify.md, ``dwellnoise``). The middle of its echo
strength (``scan.extraction.echo_middle``) moves continuously: fluted drill job, seed 100, 33
waypoints, 6 dwells each, across scatter median 0.03 mm against 0.55 mm for the fitted centres.
It lies off the axis by the section's glint, by the same at every dwell of a pose (the bit's turn
repeats there), so the calibration records it (``WaypointResidual.echo_middle_uv_mm``) and the
verify compares its own with that: not the axis, but its change.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lasercal_hw.models import FloatArray
from lasercal_hw.run.records import WaypointMeasurement
from lasercal_hw.run.two_pass import SecondPassRefit


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
    the scanner onto their middle's bearing, and the noise across the bearing the middle's.
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
        middle = refit.echo_middle(m.averaged, m.tcp_pose, predicted[k] + reference[k])
        if middle is None:
            continue
        along = np.outer(centres[k], centres[k]) / float(centres[k] @ centres[k])
        noise[k] = along @ noise[k] @ along + middle.noise_uv_m2(centres[k])
        centres[k] = middle.turned_onto(centres[k])
        reference[k] = reference[k] + recorded[k, :2]
    return centres, reference, noise
