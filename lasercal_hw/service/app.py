"""The HTTP API (``/v1``), built on FastAPI: see docs/daemon.md for every endpoint. The
routes are in ``lasercal_hw.service.routes``, one router per resource."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from importlib import resources
from pathlib import Path

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles

from lasercal_hw import __version__
from lasercal_hw.service.config import listen_address
from lasercal_hw.service.daemon import Daemon
from lasercal_hw.service.routes import calibrations, docs, events, jobs, status, trajectories, verifies
from lasercal_hw.service.routes.guard import RequestGuard
from lasercal_hw.service.routes.problems import install_problem_handlers
from lasercal_hw.service.sd_notify import notify, watchdog_interval_s

logger = logging.getLogger(__name__)


async def _watchdog() -> None:
    interval_s = watchdog_interval_s() or 1.0
    while True:  # pings only while the event loop runs: a hung loop gets restarted
        notify("WATCHDOG=1")
        await asyncio.sleep(interval_s)


def create_app(daemon: Daemon) -> FastAPI:
    """The FastAPI application serving ``daemon``."""

    @contextlib.asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        daemon.bus.attach(asyncio.get_running_loop())
        await asyncio.to_thread(daemon.start)
        daemon.state_listeners.append(lambda job_id, state: notify(f"STATUS=job {job_id}: {state}"))
        watchdog = asyncio.create_task(_watchdog()) if watchdog_interval_s() else None
        try:
            yield
        finally:
            if watchdog is not None:
                watchdog.cancel()
            daemon.bus.close_streams()
            await asyncio.to_thread(daemon.stop)

    app = FastAPI(
        title="lasercal daemon",
        version=__version__,
        lifespan=lifespan,
        openapi_url="/v1/openapi.json",
        docs_url=None,  # routes/docs.py: Swagger UI from local assets, not a CDN
        redoc_url=None,
    )
    app.state.daemon = daemon
    install_problem_handlers(app)
    listen_host, _port = listen_address(daemon.config.listen)
    app.add_middleware(RequestGuard, listen_host=listen_host, names=daemon.config.allowed_hosts)
    for resource in (status, jobs, events, calibrations, verifies, trajectories, docs):
        app.include_router(resource.router)
    docs.mount_assets(app)
    static = Path(str(resources.files("lasercal_hw.service"))) / "static"
    if static.is_dir():
        app.mount("/", StaticFiles(directory=static, html=True), name="page")
    return app
