"""What a route asks FastAPI for: the daemon it serves and, for anything that moves the arm
or changes the active calibration, a valid bearer token."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Header, Request

from lasercal_hw.service.auth import check_bearer
from lasercal_hw.service.daemon import Daemon


def get_daemon(request: Request) -> Daemon:
    """The daemon ``create_app`` serves."""
    daemon: Daemon = request.app.state.daemon
    return daemon


DaemonDep = Annotated[Daemon, Depends(get_daemon)]


def token(daemon: DaemonDep, authorization: Annotated[str | None, Header()] = None) -> None:
    """Refuse a request without the daemon's bearer token."""
    check_bearer(authorization, daemon.token)


Authorized = Depends(token)
