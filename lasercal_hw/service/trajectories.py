"""The trajectories the daemon can run: every named preset, and the designed waypoint file of
its default job (``trajectory.waypoints_file``), each with the job fragment that selects it,
so a client (the operator page) offers exactly what the daemon knows."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lasercal_hw.config import load_job
from lasercal_hw.errors import ConfigError
from lasercal_hw.run.waypoints import job_waypoints
from trajectories.presets import PRESETS, preset_names


def known_trajectories(default_job: Path | None) -> list[dict[str, Any]]:
    """``name``, ``kind`` (``waypoints_file`` or ``preset``), ``description``, ``waypoints``
    (how many) and ``job`` (what to send as a job request's ``job`` to run it)."""
    known: list[dict[str, Any]] = []
    if default_job is not None:
        try:
            job = load_job(default_job)
            designed = job.trajectory.waypoints_file
            count = len(job_waypoints(job)) if designed is not None else 0
        except ConfigError:
            designed = None  # the status says what is wrong with the default job
        if designed is not None:
            known.append({
                "name": designed.name,
                "kind": "waypoints_file",
                "description": f"designed waypoints of the daemon's job {default_job.name} ({designed})",
                "waypoints": count,
                "job": {},
            })
    for name in preset_names():
        preset = PRESETS[name]
        known.append({
            "name": name,
            "kind": "preset",
            "description": preset.description,
            "waypoints": len(preset.waypoints()),
            "job": {"trajectory": {"preset": name}},
        })
    return known
