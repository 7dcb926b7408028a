"""``lasercal run``'s summary of a cell job: each pair's agreement verdict and, where the
shared centres were used jointly, that transform's std."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

from lasercal_hw.cli import run as cli_run
from lasercal_hw.models import RodLine
from lasercal_hw.run.cell import CellReport, ScannerOutcome


def _outcome(name: str) -> ScannerOutcome:
    return ScannerOutcome(name, Path(f"{name}/result.json"), True, np.eye(4).tolist(),
                          (np.eye(6) * 1e-6).tolist(), None, None, RodLine())


def _pair(agreement: dict, joint: dict | None) -> dict:
    pair = {"from": "front", "to": "rear", "std_translation_mm": [1.0, 2.0, 3.0],
            "std_rotation_deg": [0.1, 0.2, 0.3], "agreement": agreement}
    return pair if joint is None else pair | {"joint": joint}


@pytest.mark.parametrize(("agreement", "joint", "shown", "not_shown"), [
    ({"verdict": "agree", "reason": "chi-square 27.1 <= 32.0 (16 dof, 8 shared waypoints)"},
     {"std_translation_mm": [0.9, 1.4, 3.5]}, ["agreement: agree (chi-square 27.1 <= 32.0",
                                               "used jointly: std 0.90, 1.40, 3.50 mm"], []),
    ({"verdict": "inconclusive", "reason": "1 waypoints seen by both scanners; the test needs 3"}, None,
     ["agreement: inconclusive (1 waypoints seen by both scanners"], ["jointly"]),
])
def test_the_summary_gives_each_pairs_agreement_and_joint_std(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, agreement: dict, joint: dict | None,
    shown: list[str], not_shown: list[str],
) -> None:
    screen = io.StringIO()
    monkeypatch.setattr(cli_run, "console", Console(file=screen, width=200, soft_wrap=True))
    report = CellReport(tmp_path, {n: _outcome(n) for n in ("front", "rear")}, [_pair(agreement, joint)])
    cli_run._print_cell_summary(report)
    text = screen.getvalue()
    assert "front -> rear: std 1.00, 2.00, 3.00 mm" in text
    assert all(line in text for line in shown), text
    assert not any(word in text for word in not_shown), text
