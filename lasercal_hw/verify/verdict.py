"""The verify's verdict from the identity check and the drift test, with one reason."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from lasercal_hw.models import FloatArray
from lasercal_hw.verify.drift import DriftTest
from lasercal_hw.verify.identity import IdentityCheck

Status = Literal["ok", "inconclusive", "degraded", "recalibrate"]
STATUSES: tuple[Status, ...] = ("ok", "inconclusive", "degraded", "recalibrate")


@dataclass(frozen=True)
class Verdict:
    """``ok``: consistent with the calibration, and the test could have seen a move of the
    job's tolerance; ``inconclusive``: nothing seen, but the test cannot see a move of the
    tolerance (the reason says what to do); ``degraded``: changed, but the estimated move is
    inside the tolerance; ``recalibrate``: anything else."""

    status: Status
    reason: str


CLI_MORE_DATA = (
    "measure more waypoints (--waypoints or the job's verify.waypoints, up to 20) or dwell longer "
    "(the job's dwell_s) and verify again"
)
"""What to do about a blind test with ``lasercal verify`` (a daemon gives its own advice)."""


def _blind_spot(test: DriftTest, tolerance_mm: float, tolerance_deg: float, more_data: str) -> str | None:
    """What the test cannot see of the tolerance, naming only the kinds of move (shift, turn)
    whose smallest detectable move in its weakest direction (``DriftTest.weakest``, any direction,
    not only the base axes) exceeds its tolerance (None: it sees a move of the tolerance in both)."""
    weakest = test.weakest
    blind = []
    if weakest.shift_mm > tolerance_mm:
        blind.append(
            f"a shift of {weakest.shift_mm:.2f} mm (tolerance {tolerance_mm:g} mm) along base "
            f"{_direction(weakest.shift_direction)}"
        )
    if weakest.turn_deg > tolerance_deg:
        blind.append(
            f"a turn of {weakest.turn_deg:.3f} deg (tolerance {tolerance_deg:g} deg) about base "
            f"{_direction(weakest.turn_axis)}"
        )
    if not blind:
        return None
    return (
        f"it detects ({test.detection_probability:.0%} of the time) only {' or '.join(blind)}, its "
        f"weakest direction, more than the tolerance: {more_data}"
    )


def _direction(unit: FloatArray) -> str:
    """A unit direction as ``(x, y, z)`` with two decimals, its largest component positive (a
    direction and its opposite are seen alike)."""
    signed = unit if unit[np.argmax(np.abs(unit))] > 0 else -unit
    return "(" + ", ".join(f"{value:+.2f}" for value in signed) + ")"


def with_time_note(verdict: Verdict, fraction: float | None, promised: float) -> Verdict:
    """The verdict with a note when the verify took a larger share of the calibration's
    motion and dwell than ``verify.max_time_fraction`` promised."""
    if fraction is None or fraction <= promised:
        return verdict
    # Enough digits to show the excess: the choice fills the budget by an estimate within about
    # 0.1 % of the clock, so a verify can end a hair over it ("25.0 %, over the 25 %" said nothing).
    digits = next((d for d in range(1, 6) if round(fraction * 100, d) > round(promised * 100, d)), 5)
    note = (
        f"; it took {fraction:.{digits}%} of the calibration's motion and dwell time, over the "
        f"{promised:.0%} promised (verify.max_time_fraction)"
    )
    return Verdict(verdict.status, verdict.reason + note)


def decide(
    identity: list[IdentityCheck],
    test: DriftTest | None,
    tolerance_mm: float,
    tolerance_deg: float,
    missing_reason: str | None = None,
    more_data: str = CLI_MORE_DATA,
) -> Verdict:
    """The verdict; ``test`` is None when too few waypoints were measured
    (``missing_reason`` says why); ``more_data`` is what an inconclusive verdict advises."""
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
        blind = _blind_spot(test, tolerance_mm, tolerance_deg, more_data)
        if blind is not None:
            agree = f"measurements agree with the calibration ({statistic}), but {blind}"
            return Verdict("inconclusive", agree)
        return Verdict("ok", f"measurements agree with the calibration: {statistic}")
    if not test.rigid:
        return Verdict(
            "recalibrate",
            f"measurements disagree ({statistic}) in a way no rigid scanner move explains (post-fit "
            f"chi-square {test.post_fit_chi_square:.1f} > {test.post_fit_threshold:.1f}): "
            "check the rod or tool" + _range_note(test),
        )
    inside = shift_mm <= tolerance_mm and turn_deg <= tolerance_deg
    tolerance = f"tolerance {tolerance_mm:g} mm, {tolerance_deg:g} deg"
    if inside:
        return Verdict("degraded", f"{move}, inside the {tolerance} ({statistic})" + _range_note(test))
    return Verdict("recalibrate", f"{move}, beyond the {tolerance} ({statistic})" + _range_note(test))


def _range_note(test: DriftTest) -> str:
    """Where one range change explains a flagged test as well: say so, and what to do."""
    change = test.range_change
    if change is None or not change.explains:
        return ""
    return (
        f"; the residuals also fit one range change of {change.offset_m * 1e3:+.2f} +- "
        f"{change.std_m * 1e3:.2f} mm along every beam (remainder chi-square "
        f"{change.remainder_chi_square:.1f} <= {change.remainder_threshold:.1f}): the scanner may "
        "read its ranges differently than at the calibration, as one does while it warms up after "
        "power-on; if it was powered on recently, let it warm up and verify again"
    )
