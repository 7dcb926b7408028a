"""The trajectories the daemon can run: every named preset, and the designed waypoint file of
its default job (``trajectory.waypoints_file``; a cell job: each scanner's own, and then no
preset, which its scanners would not visit), each with the job fragment that selects it, so a
client (the operator page) offers exactly what the daemon knows."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lasercal_hw.config import JobConfig, load_job
from lasercal_hw.errors import ConfigError
from lasercal_hw.run.waypoints import planned_waypoints
from trajectories.presets import PRESETS, preset_names


def _load(default_job: Path | None) -> JobConfig | None:
    """The default job; None without one or when it cannot be read (the status says why)."""
    try:
        return None if default_job is None else load_job(default_job)
    except ConfigError:
        return None


def _designed(job: JobConfig, default_job: Path) -> dict[str, Any] | None:
    """The default job's own trajectory: its designed waypoint file, or a cell job's scanners'
    trajectories together (each scanner's own); None when it has neither (or its waypoints
    cannot be read)."""
    try:
        if job.scanners:
            counts = {name: len(planned_waypoints(job.for_scanner(name))) for name in job.scanner_names()}
            return {
                "name": "each scanner's own",
                "kind": "cell",
                "description": f"the daemon's job {default_job.name}: "
                + ", ".join(f"{name} {count} waypoints" for name, count in counts.items()),
                "waypoints": sum(counts.values()),
                "job": {},
            }
        designed = job.trajectory.waypoints_file
        if designed is None:
            return None
        return {
            "name": designed.name,
            "kind": "waypoints_file",
            "description": f"designed waypoints of the daemon's job {default_job.name} ({designed})",
            "waypoints": len(planned_waypoints(job)),
            "job": {},
        }
    except ConfigError:
        return None


def known_trajectories(default_job: Path | None) -> list[dict[str, Any]]:
    """``name``, ``kind`` (``waypoints_file``, ``cell``: each scanner's own, or ``preset``),
    ``description``, ``waypoints`` (how many) and ``job`` (what to send as a job request's
    ``job`` to run it)."""
    known: list[dict[str, Any]] = []
    job = _load(default_job)
    designed = _designed(job, default_job) if job is not None and default_job is not None else None
    if designed is not None:
        known.append(designed)
    if job is not None and job.scanners_with_own_trajectory():
        return known  # a request naming a preset is refused there (job_request.resolve_job)
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
