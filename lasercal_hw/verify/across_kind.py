"""A plain rod's verify compares centres placed alike across the bearing: by the middle of the
rod's echo where both the calibration's dwell and the verify's read one, by the fit where either
did not.

The extraction places a plain rod's centre across its bearing at the middle of its echo strength
where it reads one (``scan.extraction.echo_middle``), at the fit's otherwise. At a pose where the
middle is read at some dwells and not at others the two kinds of centre lie apart: the default
job's waypoint 11 (the rod at 1.03 m on 7 beams), 1.94 mm across, three of four false alarms in
seeds 0-369, each where the calibration's dwell read no middle and the verify's did
(docs/lab/verify-log.md). The calibration records how far the middle moved each of its centres
(``WaypointResidual.echo_middle_move_uv_mm``), so the verify can take the fit on both sides.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from lasercal_hw.models import FloatArray
from lasercal_hw.run.records import WaypointMeasurement
from lasercal_hw.run.two_pass import SecondPassRefit
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction import ExtractionSettings

#: The extraction with the centre placed across by the fit alone.
FIT_ACROSS = replace(ExtractionSettings(), echo_middle_levels=())


def placed_alike(
    refit: SecondPassRefit,
    measurements: Sequence[WaypointMeasurement],
    refitted: Sequence[WaypointMeasurement],
    recorded_moves: FloatArray,
    reference: FloatArray,
    background: AveragedScan | None,
) -> tuple[list[WaypointMeasurement], FloatArray, list[tuple[int, str]]]:
    """The verify's re-fitted centres (``refitted``, of ``measurements`` as they were measured)
    and the calibration's residuals (``reference``, N rows) with each pair placed alike across
    the bearing: where the calibration's centre was moved by its echo middle
    (``recorded_moves``: N rows of ``recorded_echo_middle_moves``) and this one's was not, the
    residual without that move; where this one's was and the calibration's was not, this dwell
    fitted again without the middle. Where nothing is recorded (a fluted rod, an older file)
    both are as they were. Also the waypoints (index, reason) whose fit without the middle
    failed: left out, as a centre not fitted again is."""
    by_index = {m.index: m for m in measurements}
    reference = np.array(reference, dtype=float)
    alike: list[WaypointMeasurement] = []
    failed: list[tuple[int, str]] = []
    for k, m in enumerate(refitted):
        recorded = recorded_moves[k]
        if not np.isfinite(recorded).all():
            alike.append(m)
            continue
        recorded_read = bool(np.any(recorded != 0.0))
        read = m.centre.echo_middle_move_uv_m is not None
        if recorded_read and not read:
            reference[k] = reference[k] - recorded
        elif read and not recorded_read:
            fitted, not_fitted = refit.centres([by_index[m.index]], background, FIT_ACROSS)
            if not_fitted:
                failed.extend(not_fitted)
                continue
            m = fitted[0]
        alike.append(m)
    failed_indices = {index for index, _ in failed}
    kept = [k for k, m in enumerate(refitted) if m.index not in failed_indices]
    return alike, reference[kept], failed
