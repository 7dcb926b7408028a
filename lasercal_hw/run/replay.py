"""Solve a recorded run again, offline: ``lasercal solve session.mcap``.

The recording holds the job, every scan and the ``observation`` events of the live run.
The averaged scans and the background are rebuilt from the recorded scans by the same rule
the live run used (``lasercal_hw.run.resume``) and solved by the same two-pass function
(``lasercal_hw.run.sequencer.solve_two_pass``), so the replay reproduces the live result.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from lasercal_hw.config import JobConfig
from lasercal_hw.errors import CalibrationError, ConfigError
from lasercal_hw.run.resume import recorded_job, resume_state
from lasercal_hw.run.sequencer import TwoPassSolution, solve_two_pass
from lasercal_hw.session.reader import read_session

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RecordingSolution:
    """The two-pass solution of a recording, with what it was computed from."""

    job: JobConfig
    solution: TwoPassSolution
    skipped: dict[int, str]
    truncated: bool


def solve_recording(path: str | Path) -> RecordingSolution:
    """Re-run extraction and the solver on a ``session.mcap`` written by ``lasercal run``."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"recording {str(path)!r} does not exist; pass the session.mcap of a run")
    recording = read_session(path)
    job, _ = recorded_job(recording)
    state = resume_state(recording)
    if not state.measurements:
        raise CalibrationError(
            f"{path} holds no completed waypoint observation; nothing to solve (resume the run with "
            f"`lasercal run --resume {path}`)"
        )
    if recording.truncated:
        logger.warning("%s was not closed (%s); solving what it holds", path, recording.truncation_reason)
    solution = solve_two_pass(state.measurements, job, state.background)
    return RecordingSolution(
        job=job,
        solution=solution,
        skipped={s.index: s.reason for s in state.skipped},
        truncated=recording.truncated,
    )
