"""The dry run's fake cell: started by a run for itself, or once by a cell job for all its
scanners and handed to each scanner's run (``RunRequest.fake_cell``), so the scanners of a
cell are calibrated in one world by one fake robot, as on a real cell."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lasercal_hw.errors import DeviceError
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.run.events import EventSink, Stage


@dataclass(frozen=True)
class DryRunCell:
    """A running fake cell (``fakes.cell_process.FakeCellProcess``) and the scene it serves."""

    process: Any
    scene: Path


def start_fake_cell(
    scene: Path, stack: contextlib.ExitStack, sink: EventSink, cancel: CancelToken
) -> DryRunCell:
    """Start a fake cell on the scene file ``scene``, stopped by ``stack``; if it
    dies while in use, ``cancel`` fails with a DeviceError that says so, and the run using it
    stops at once."""
    from fakes.cell_process import FakeCellProcess  # the dry-run step only: nothing else needs a fake

    sink.emit("stage", "starting a fake cell for the dry run", stage=Stage.FAKE_CELL)

    def died(death: str) -> None:
        cancel.fail(DeviceError(f"the dry run's fake cell died: {death}"))

    process = stack.enter_context(FakeCellProcess(scene=scene, on_death=died))
    return DryRunCell(process, scene)
