"""The verify's verdict from the identity check and the drift test, with one reason."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from lasercal_hw.verify.drift import DriftTest
from lasercal_hw.verify.identity import IdentityCheck

Status = Literal["ok", "degraded", "recalibrate"]


@dataclass(frozen=True)
class Verdict:
    """``ok``: consistent with the calibration; ``degraded``: changed, but the estimated
    move is inside the job's tolerance; ``recalibrate``: anything else."""

    status: Status
    reason: str


def decide(
    identity: list[IdentityCheck],
    test: DriftTest | None,
    tolerance_mm: float,
    tolerance_deg: float,
    missing_reason: str | None = None,
) -> Verdict:
    """The verdict; ``test`` is None when too few waypoints were measured
    (``missing_reason`` says why)."""
    changed = [check.describe() for check in identity if not check.matches]
    if changed:
        return Verdict("recalibrate", "; ".join(changed))
    if test is None:
        return Verdict("recalibrate", missing_reason or "no waypoint could be measured")
    statistic = (
        f"chi-square {test.chi_square:.1f} {'>' if test.changed else '<='} {test.threshold:.1f} "
        f"({test.dof} dof, false-alarm rate {test.false_alarm_rate:.0%})"
    )
    shift_mm, shift_std = test.shift_norm_mm()
    turn_deg, turn_std = test.turn_norm_deg()
    move = (
        f"scanner moved {shift_mm:.2f} +- {shift_std:.2f} mm and turned {turn_deg:.3f} +- {turn_std:.3f} deg"
    )
    if not test.changed:
        return Verdict("ok", f"measurements agree with the calibration: {statistic}")
    if not test.rigid:
        return Verdict(
            "recalibrate",
            f"measurements disagree ({statistic}) in a way no rigid scanner move explains (post-fit "
            f"chi-square {test.post_fit_chi_square:.1f} > {test.post_fit_threshold:.1f}): "
            "check the rod or tool",
        )
    inside = shift_mm <= tolerance_mm and turn_deg <= tolerance_deg
    tolerance = f"tolerance {tolerance_mm:g} mm, {tolerance_deg:g} deg"
    if inside:
        return Verdict("degraded", f"{move}, inside the {tolerance} ({statistic})")
    return Verdict("recalibrate", f"{move}, beyond the {tolerance} ({statistic})")
