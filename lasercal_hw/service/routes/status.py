"""``/v1/health`` and ``/v1/status``: the daemon itself."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from lasercal_hw import __version__
from lasercal_hw.service.routes.deps import DaemonDep

router = APIRouter()


@router.get("/v1/health")
def health() -> dict[str, Any]:
    """Liveness without device I/O."""
    return {"ok": True, "version": __version__}


@router.get("/v1/status")
def status(daemon: DaemonDep) -> dict[str, Any]:
    """Daemon, devices, active calibration and the running (or last) job."""
    return daemon.status()
