"""``/v1/trajectories``: what the daemon can run (presets and its designed waypoints)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from lasercal_hw.service.routes.deps import DaemonDep
from lasercal_hw.service.trajectories import known_trajectories

router = APIRouter()


@router.get("/v1/trajectories")
def trajectories(daemon: DaemonDep) -> dict[str, Any]:
    """Every trajectory a job may name, with the job fragment that selects it."""
    return {"trajectories": known_trajectories(daemon.config.default_job)}
