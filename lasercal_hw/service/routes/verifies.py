"""``/v1/verifies``: the checks of the active calibration, newest first."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from lasercal_hw.service.routes.deps import DaemonDep

router = APIRouter()


@router.get("/v1/verifies")
def verifies(daemon: DaemonDep) -> dict[str, Any]:
    """Verify results, newest first."""
    return {"verifies": daemon.history.verifies()}
