"""A running visit's time left: the parts of its plan (``run.timing``) still ahead, the moves
scaled by how long the arm's moves so far took against the plan.

A UR's speed slider, or a controller slower than the model, stretches every move alike, so the
ratio of the moves made (with their settling) to their planned time carries over to the moves
ahead; dwells and the background are the job's own and are taken as planned. Where the UR5
model cannot plan a move (``visit_timeline`` gives None), a move ahead counts the mean of the
moves made so far (none before the first one).
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field

import numpy as np

from lasercal_hw.config import JobConfig
from lasercal_hw.models import FloatArray
from lasercal_hw.run.timing import background_s, dwell_each_s, visit_timeline


@dataclass
class TimeLeft:
    """The plan of a visit and the moves made against it."""

    #: The planned move to the retract pose (None: not planned).
    to_retract_s: float | None
    background_s: float
    #: The planned move to each waypoint ahead, by index (empty: not planned).
    move_s: dict[int, float]
    dwell_each_s: float
    _planned_done_s: float = field(default=0.0, init=False)
    _actual_done_s: float = field(default=0.0, init=False)
    _actual_all_s: float = field(default=0.0, init=False)
    _moves_done: int = field(default=0, init=False)

    @classmethod
    def plan(cls, job: JobConfig, waypoints: FloatArray, pending: list[int]) -> TimeLeft:
        """The visit of the ``pending`` waypoints in order (from the UR home posture, through
        the retract pose and its background)."""
        timeline = visit_timeline(job, np.asarray(waypoints)[pending]) if pending else None
        if timeline is None:
            return cls(None, background_s(job), {}, dwell_each_s(job))
        moves = dict(zip(pending, timeline.moves_s, strict=True))
        return cls(timeline.to_retract_s, timeline.background_s, moves, timeline.dwell_each_s)

    def moved(self, target: int | None, actual_s: float) -> None:
        """A first move to ``target`` (None: the retract pose) took ``actual_s`` with its settling."""
        planned_s = self.to_retract_s if target is None else self.move_s.get(target)
        self._moves_done += 1
        self._actual_all_s += actual_s
        if planned_s is not None:
            self._planned_done_s += planned_s
            self._actual_done_s += actual_s

    def seconds(
        self, *, retract_ahead: bool, background_ahead: bool, moves_ahead: Collection[int], dwells_ahead: int
    ) -> float:
        """The time left: the moves, background and dwells still ahead."""
        moves_s = [self.to_retract_s if retract_ahead else 0.0] + [self.move_s.get(i) for i in moves_ahead]
        scale = self._actual_done_s / self._planned_done_s if self._planned_done_s > 0.0 else 1.0
        unplanned_s = self._actual_all_s / self._moves_done if self._moves_done else 0.0
        motion_s = sum(unplanned_s if s is None else scale * s for s in moves_s)
        return motion_s + (self.background_s if background_ahead else 0.0) + dwells_ahead * self.dwell_each_s
