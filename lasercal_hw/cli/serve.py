"""``lasercal serve``: the calibration daemon (HTTP API, live events, calibration history)."""

from __future__ import annotations

import sys
import threading
from pathlib import Path
from typing import Annotated, Any

import typer

from lasercal_hw.cli.common import DryRunOption, FoxgloveOption, FoxglovePortOption, foxglove_line

ConfigOption = Annotated[Path | None, typer.Option("--config", help="Daemon configuration (TOML).")]
ListenOption = Annotated[
    str | None,
    typer.Option("--listen", help="HOST:PORT to listen on (default 127.0.0.1:8766; port 0: any free)."),
]
DataDirOption = Annotated[
    Path | None, typer.Option("--data-dir", help="History, job folders and token (~/.local/state/lasercal).")
]

RebuildOption = Annotated[
    bool,
    typer.Option(
        "--rebuild-history",
        help="Rebuild the history database from the job folders (result.json, recordings), then exit.",
    ),
]
LogFormatOption = Annotated[
    str | None,
    typer.Option(
        "--log-format",
        metavar="text|json",
        help="The daemon's log on stderr: text (a line a person reads) or json (one object a line).",
    ),
]

READY_PREFIX = "lasercal daemon listening on "
STREAM_GRACE_S = 4.0
"""At SIGTERM, how long event streams stay open for the running job's final state (uvicorn
waits 5 s for open connections)."""


def url_host(host: str) -> str:
    """``host`` as it stands in a URL: an IPv6 address in brackets."""
    return f"[{host}]" if ":" in host else host


def serve_command(
    config: ConfigOption = None,
    listen: ListenOption = None,
    data_dir: DataDirOption = None,
    dry_run: DryRunOption = False,
    foxglove: FoxgloveOption = False,
    foxglove_port: FoxglovePortOption = 8765,
    rebuild_history: RebuildOption = False,
    log_format: LogFormatOption = None,
) -> None:
    """Run the calibration daemon until SIGTERM or Ctrl-C (a running job's arm is stopped first).

    Prints one line 'lasercal daemon listening on http://HOST:PORT (token in FILE)' once it
    accepts connections (with --foxglove, then one line with the live view's ws:// address);
    notifies systemd (READY=1, STATUS, WATCHDOG) when run under it.
    """
    import uvicorn

    from lasercal_hw.live.foxglove import FoxgloveLiveView
    from lasercal_hw.service import daemon_log
    from lasercal_hw.service.app import create_app
    from lasercal_hw.service.config import listen_address, load_daemon_config
    from lasercal_hw.service.daemon import Daemon
    from lasercal_hw.service.runners import build_runners
    from lasercal_hw.service.sd_notify import notify

    overrides: dict[str, Any] = {
        "listen": listen,
        "data_dir": data_dir,
        "dry_run": dry_run or None,
        "log_format": log_format,
    }
    settings = load_daemon_config(config, overrides)
    daemon_log.configure(settings.log_format)
    if rebuild_history:
        from lasercal_hw.service.rebuild import rebuild_history as rebuild
        from lasercal_hw.service.store import DB_FILE

        print(rebuild(settings.data_dir).line(settings.data_dir / DB_FILE))
        return
    live = FoxgloveLiveView(port=foxglove_port) if foxglove else None  # lives as long as the process
    daemon = Daemon(settings, runners=lambda folder_of: build_runners(folder_of, live=live))
    host, port = listen_address(settings.listen)

    class Server(uvicorn.Server):
        """uvicorn, announcing readiness once the socket listens and ending event streams at exit."""

        async def startup(self, sockets: Any = None) -> None:
            await super().startup(sockets)
            if not self.started:
                return
            bound_port = self.servers[0].sockets[0].getsockname()[1]
            url = f"http://{url_host(host)}:{bound_port}"
            print(f"{READY_PREFIX}{url} (token in {settings.token_path})", flush=True)
            if live is not None:
                print(foxglove_line(live.url), flush=True)
            notify("READY=1")

        def handle_exit(self, sig: int, frame: Any) -> None:
            notify("STOPPING=1")
            daemon.jobs.shutdown(timeout_s=0.0)  # start stopping the arm now; lifespan waits for it
            threading.Thread(target=end_streams_after_job, name="end-streams", daemon=True).start()
            super().handle_exit(sig, frame)

    def end_streams_after_job() -> None:
        """Streams end once the running job has stored and sent its final state."""
        daemon.jobs.shutdown(timeout_s=STREAM_GRACE_S)
        daemon.bus.close_streams_soon()

    server = Server(
        uvicorn.Config(
            create_app(daemon),
            host=host,
            port=port,
            log_level="warning",
            timeout_graceful_shutdown=5,
            lifespan="on",
        )
    )
    server.run()
    if not server.started:
        sys.exit(3)
