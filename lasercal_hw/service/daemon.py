"""The daemon's parts put together: data folder, token, history, event bus, the door to
its devices, job manager, device monitor and, with ``dry_run``, the fake cell it serves
instead of hardware."""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lasercal_hw import __version__
from lasercal_hw.errors import ConfigError, LasercalError
from lasercal_hw.service.auth import ensure_token
from lasercal_hw.service.calibrations import CalibrationHistory
from lasercal_hw.service.config import DaemonConfig
from lasercal_hw.service.errors import ServiceError, StorageFullError
from lasercal_hw.service.events import EventBus
from lasercal_hw.service.folder_lock import DataFolderLock
from lasercal_hw.service.health import DEFAULT_SCANNER, scanner_health
from lasercal_hw.service.jobs import JobManager, Runner
from lasercal_hw.service.monitor import DeviceMonitor
from lasercal_hw.service.rebuild import job_folders
from lasercal_hw.service.store import DB_FILE, REBUILD_HINT, HistoryStore, utc_now

if TYPE_CHECKING:
    from drivers.access import DeviceAccess
    from fakes.cell_process import FakeCellProcess
    from lasercal_hw.service.runners import CalibrationFolder

logger = logging.getLogger(__name__)

API_VERSION = 1


def require_history(data_dir: Path) -> None:
    """Refuse to start an empty history beside job folders: a missing or emptied database
    would hide every job and calibration (ConfigError saying how to rebuild it)."""
    database = data_dir / DB_FILE
    if database.exists() and database.stat().st_size > 0:
        return
    folders = job_folders(data_dir)
    if folders:
        found = "is empty" if database.exists() else "is missing"
        raise ConfigError(
            f"the history database {database} {found} but {data_dir / 'jobs'} holds {len(folders)} job "
            f"folders: rebuild the history from them with {REBUILD_HINT}, or move the jobs folder aside "
            "to start a new history"
        )


class Daemon:
    """Everything ``lasercal serve`` holds; ``start`` and ``stop`` bracket the server's life."""

    def __init__(
        self,
        config: DaemonConfig,
        runners: Callable[[CalibrationFolder], dict[str, Runner]] | None = None,
    ) -> None:
        if not config.loopback_only and config.token_file is None:
            raise ConfigError(
                f"refusing to listen on {config.listen} (not loopback) without a configured "
                "token: set token_file in the daemon configuration (docs/daemon.md)"
            )
        self.config = config
        self.data_dir = config.data_dir
        try:
            self.data_dir.mkdir(parents=True, exist_ok=True, mode=0o700)
        except OSError as exc:
            raise ConfigError(
                f"cannot create the data folder {self.data_dir}: {exc.strerror or exc}"
            ) from None
        # the folder is this process's before anything in it is read or written (a second daemon
        # would mark this one's running job interrupted); given back if the start fails
        self.folder_lock = DataFolderLock(
            self.data_dir,
            "refusing to start a second daemon on it: stop that one first, or give this one another "
            "--data-dir",
        ).acquire()
        try:
            self._open(config, runners)
        except BaseException:
            self.folder_lock.release()
            raise

    def _open(
        self, config: DaemonConfig, runners: Callable[[CalibrationFolder], dict[str, Runner]] | None
    ) -> None:
        """Everything in the data folder, once its lock is held: token, history, jobs (those a
        crash left running marked interrupted)."""
        try:
            self.token = ensure_token(config.token_path)
        except OSError as exc:  # a full disk or a read-only folder on first start
            why = exc.strerror or exc
            raise ConfigError(f"cannot write the token file {config.token_path}: {why}") from None
        require_history(self.data_dir)
        self.store = HistoryStore(self.data_dir / DB_FILE)
        self.bus = EventBus(self.store)
        self.history = CalibrationHistory(self.store, self.bus)
        from drivers.access import DeviceAccess  # the daemon's one door to its devices

        self.devices: DeviceAccess = DeviceAccess(
            config.robot_host, config.scanner_url,
            scanner_urls={name: scanner.url for name, scanner in config.scanners.items()},
        )
        self.fake_cell: FakeCellProcess | None = None
        self._stopping = False
        self.started_utc = utc_now()
        if runners is None:
            from lasercal_hw.service.runners import build_runners

            runners = build_runners
        self.jobs = JobManager(
            self.store,
            self.bus,
            self.data_dir,
            runners(self.calibration_folder),
            self.history,
            self.devices,
            default_job=config.default_job,
            dry_run_daemon=config.dry_run,
            on_state=self._on_state,
            dry_run_scene=config.dry_run_scene if config.dry_run else None,
        )
        try:
            self.interrupted = self.jobs.recover()
        except StorageFullError as exc:
            raise ConfigError(f"cannot start: {exc.message}") from None
        self.monitor: DeviceMonitor | None = None
        self.state_listeners: list[Callable[[str, str], None]] = []

    def calibration_folder(self, calibration_id: str) -> Path | None:
        """The folder of the calibration ``calibration_id`` in the history, or None."""
        found = self.store.calibration(calibration_id)
        return None if found is None else found[1]

    def _on_state(self, job_id: str, state: str) -> None:
        for listener in self.state_listeners:
            listener(job_id, state)

    def start(self) -> None:
        """Start the fake cell (dry run) and the device polling; announce the start (the jobs a
        crash left running were marked interrupted when the daemon was built)."""
        if self.config.dry_run:
            self._start_fake_cell()
        self.monitor = DeviceMonitor(self.devices, self.config.status_poll_s)
        self.monitor.start()
        try:
            self.bus.publish(
                "daemon",
                {
                    "message": f"lasercal {__version__} daemon started",
                    "dry_run": self.config.dry_run,
                    "interrupted_jobs": self.interrupted,
                },
            )
        except StorageFullError as exc:  # reads still work; new jobs are refused until space is back
            logger.warning("%s", exc.message)

    def _start_fake_cell(self) -> None:
        """The dry-run daemon's fake cell, its devices the daemon's; started again if it dies.
        From now on this process (and its children) connects to loopback addresses only."""
        from drivers.loopback import LOOPBACK_ONLY_ENV
        from fakes.cell_process import FakeCellProcess

        os.environ.setdefault(LOOPBACK_ONLY_ENV, "a dry-run daemon talks only to its fake cell")

        self.fake_cell = FakeCellProcess(
            scene=self.config.dry_run_scene, on_death=self._fake_cell_died,
            serving="serving the dry-run daemon",
        ).start()
        self.devices.robot_host = self.fake_cell.robot_host
        self.devices.scanner_url = self.fake_cell.scanner_url
        scene_scanners = self.fake_cell.info.get("scanners", {})
        named = {name: entry["scanner_url"] for name, entry in scene_scanners.items()}
        # a scene of named scanners ([scanners.NAME]) is a cell; one [scanner] table is one scanner
        self.devices.scanner_urls = {} if set(named) <= {DEFAULT_SCANNER} else named

    def _fake_cell_died(self, why: str) -> None:
        if self._stopping:
            return
        if self.fake_cell is not None:
            self.fake_cell.stop()  # reaps the dead child, closes its files
        try:
            self._start_fake_cell()
        except LasercalError as exc:
            logger.error("the fake cell could not be started again: %s", exc)
            return
        scanners = ", ".join(url for _, url in self.devices.scanners() if url)
        message = f"{why}; started a new one (robot {self.devices.robot_host}, scanners {scanners})"
        logger.warning("%s", message)
        with contextlib.suppress(ServiceError):
            self.bus.publish("daemon", {"message": message, "dry_run": True})

    def stop(self) -> None:
        """Stop a running job's arm (the job becomes ``interrupted``) and release everything."""
        self._stopping = True
        self.jobs.shutdown()
        if self.monitor is not None:
            self.monitor.stop()
        if self.fake_cell is not None:
            self.fake_cell.stop()
        self.store.close()
        self.folder_lock.release()

    def health(self) -> dict[str, Any]:
        """``GET /v1/health``: liveness, and per scanner its calibration's health (from the
        history and the monitor's last readings, no device I/O)."""
        unread = {"known": False, "calibration": None, "read_utc": None, "error": "not read yet"}
        robot_reading = self.monitor.robot_calibration() if self.monitor else unread
        now = datetime.now(UTC)
        scanners = []
        for name, url in self.devices.scanners():
            active = self.history.active_summary(name)
            last_verify = None if active is None else self.history.latest_verify(active["id"])
            earlier = [] if active is None else self.history.earlier_than(active)
            scanners.append(scanner_health(name, url, active, last_verify, robot_reading, now, earlier))
        return {
            "ok": True, "version": __version__, "api_version": API_VERSION, "time_utc": now.isoformat(),
            "robot_calibration": robot_reading, "scanners": scanners,
        }

    def status(self) -> dict[str, Any]:
        """``GET /v1/status``: from memory and the store, no device I/O."""
        unread: dict[str, Any] = {"robot": None, "scanner": None, "scanners": []}
        devices = self.monitor.snapshot() if self.monitor else unread
        return {
            "daemon": {
                "version": __version__,
                "api_version": API_VERSION,
                "dry_run": self.config.dry_run,
                "started_utc": self.started_utc,
                "data_dir": str(Path(self.data_dir).resolve()),
            },
            **devices,
            "active_calibration": self.history.active_summary(),
            "job": job.as_json() if (job := self.jobs.current()) is not None else None,
        }
