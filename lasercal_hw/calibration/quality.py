"""Quality gates: is a calibration result good enough to use?"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lasercal_hw.calibration.result import CalibrationResult
from lasercal_hw.config import QualityConfig


@dataclass(frozen=True)
class GateCheck:
    """One gate: the measured value, its limit, and whether it passed."""

    name: str
    value: float
    limit: float
    unit: str
    passed: bool

    def describe(self) -> str:
        """One line for the operator."""
        verdict = "ok" if self.passed else "FAILED"
        return f"{self.name}: {self.value:.3g} {self.unit} (limit {self.limit:.3g} {self.unit}) {verdict}"


@dataclass(frozen=True)
class Verdict:
    """The outcome of every gate."""

    checks: list[GateCheck] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        """True when every gate passed."""
        return all(check.passed for check in self.checks)

    def failures(self) -> list[str]:
        """Descriptions of the gates that failed."""
        return [check.describe() for check in self.checks if not check.passed]

    def as_dict(self) -> dict[str, object]:
        """JSON-ready form for result documents and the recording."""
        return {
            "passed": self.passed,
            "checks": [
                {"name": c.name, "value": c.value, "limit": c.limit, "unit": c.unit, "passed": c.passed}
                for c in self.checks
            ],
        }


def evaluate_gates(result: CalibrationResult, gates: QualityConfig, waypoint_count: int) -> Verdict:
    """Check a solver result against the configured gates.

    ``waypoint_count`` is the number of waypoints the run planned; the outlier fraction is
    taken over the observations the solver was given.
    """
    used = sum(1 for r in result.residuals if r.used)
    given = max(len(result.residuals), 1)
    outlier_fraction = len(result.outliers) / given
    std_translation_mm = float(np.max(np.abs(np.atleast_1d(result.std_translation_mm))))
    std_rotation_deg = float(np.max(np.abs(np.atleast_1d(result.std_rotation_deg))))

    def check(name: str, value: float, limit: float, unit: str, at_most: bool = True) -> GateCheck:
        passed = value <= limit if at_most else value >= limit
        return GateCheck(name, float(value), float(limit), unit, bool(passed))

    return Verdict(
        [
            check("residual RMS", result.rms_residual_mm, gates.max_rms_residual_mm, "mm"),
            check("largest translation std", std_translation_mm, gates.max_std_translation_mm, "mm"),
            check("largest rotation std", std_rotation_deg, gates.max_std_rotation_deg, "deg"),
            check("outlier fraction", outlier_fraction, gates.max_outlier_fraction, ""),
            check(
                f"observations used (of {waypoint_count} waypoints)",
                used,
                gates.min_observations,
                "",
                at_most=False,
            ),
        ]
    )
