"""Browser tests: Debian's Chromium driven by Selenium through /usr/bin/chromedriver (nothing
downloads a browser), against a real ``lasercal serve --dry-run`` on a loopback port."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.daemon_helpers import QUICK_JOB, DaemonProcess

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
ARTIFACTS = Path(__file__).parent / "artifacts"
WINDOW = (1400, 1500)
CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
)


def _require_chromium() -> None:
    missing = [str(p) for p in (CHROMIUM, CHROMEDRIVER) if not p.exists()]
    if not missing:
        return
    message = (f"{' and '.join(missing)} missing: install the Debian packages `chromium chromium-driver` "
               "(apt-get install -y chromium chromium-driver)")
    if os.environ.get("CI") == "true":
        pytest.fail(f"CI needs the browser tests: {message}")
    pytest.skip(message)


def _default_job_toml() -> str:
    """The page chooses the trajectory and the dwell; the rest of the integration tests' quick
    job (fast joint moves, acquisition that rides out a loaded machine's scan gaps) is the
    daemon's default job, without the report PNG (the page never shows it; rendering it took
    1.5-7 s of each run and verify)."""
    tables = {table: fields for table, fields in QUICK_JOB.items() if table != "trajectory"}
    lines = []
    for table, fields in (tables | {"output": {"report": False}}).items():
        lines += [f"[{table}]", *(f"{key} = {json.dumps(value)}" for key, value in fields.items())]
    return "\n".join(lines) + "\n"


def _serve(folder: Path, daemon_toml: str) -> Iterator[DaemonProcess]:
    """``lasercal serve --dry-run`` on a free loopback port, configured by ``daemon_toml`` in
    ``folder``, with a fresh data folder there; stopped at the end."""
    _require_chromium()
    config = folder / "daemon.toml"
    config.write_text(daemon_toml, encoding="utf-8")
    process = DaemonProcess(folder / "data", config=config)
    try:
        yield process.start()
    finally:
        process.stop()


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    """The dry-run daemon of one scanner, its default job the quick job's settings."""
    folder = tmp_path_factory.mktemp("page-daemon")
    (folder / "job.toml").write_text(_default_job_toml(), encoding="utf-8")
    yield from _serve(folder, 'default_job = "job.toml"\n')


@pytest.fixture(scope="module")
def cell_daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    """The dry-run daemon serving the two-scanner fake cell (fakes/scenes/two_scanners.toml), its
    default job examples/cell.toml on the first waypoints of each scanner (tests/run/test_cell.py)."""
    from tests.run.test_cell import SCENE, write_job

    folder = tmp_path_factory.mktemp("cell-page-daemon")
    job = write_job(folder)
    yield from _serve(folder, f'default_job = "{job.name}"\ndry_run_scene = "{SCENE}"\n')


@pytest.fixture(scope="session")
def browser() -> Iterator[Any]:
    """Headless Chromium with a fresh profile, through the system chromedriver: one for the
    worker's browser tests (their modules share an xdist group; each test loads its own
    daemon's page, on its own port: nothing of one page's state reaches another)."""
    _require_chromium()
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    os.environ.setdefault("SE_OFFLINE", "true")  # Selenium Manager must never fetch a browser or driver
    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    with tempfile.TemporaryDirectory(prefix="lasercal-chromium-") as profile:
        for flag in (*CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--window-size={WINDOW[0]},{WINDOW[1]}"):
            options.add_argument(flag)
        driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=options)
        try:
            yield driver
        finally:
            driver.quit()


@pytest.fixture(scope="module")
def artifacts() -> Path:
    """Where screenshots and figures go (gitignored; CI keeps them as artefacts)."""
    ARTIFACTS.mkdir(exist_ok=True)
    return ARTIFACTS
