"""Browser tests: Debian's Chromium driven by Selenium through /usr/bin/chromedriver (nothing
downloads a browser), against a real ``lasercal serve --dry-run`` on a loopback port."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
ARTIFACTS = Path(__file__).parent / "artifacts"
READY_PREFIX = "lasercal daemon listening on "
START_TIMEOUT_S = 120.0
STOP_TIMEOUT_S = 30.0
WINDOW = (1400, 1500)
# The page is under test, not the fake cell's timing: on a CPU-starved machine the fake scanner's
# 40 Hz stream can stall for a few hundred ms, which a real run rightly treats as a fault.
TOLERANT_JOB = "[acquisition]\nmax_missed_scans = 80\nmax_attempts = 5\nmin_scan_fraction = 0.2\n"
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


@dataclass(frozen=True)
class Daemon:
    """A running dry-run daemon: where it listens and its token."""

    base_url: str
    token: str
    data_dir: Path


def _ready_line(process: subprocess.Popen[str]) -> str:
    """The daemon's 'listening on' line, or a failure naming what it printed instead."""
    lines: queue.Queue[str | None] = queue.Queue()

    def read() -> None:
        assert process.stdout is not None
        for line in process.stdout:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=read, daemon=True).start()
    seen = []
    while True:
        try:
            line = lines.get(timeout=START_TIMEOUT_S)
        except queue.Empty:
            pytest.fail(f"lasercal serve did not say it was listening within {START_TIMEOUT_S:.0f} s: {seen}")
        if line is None:
            pytest.fail(f"lasercal serve exited ({process.wait()}) before listening: {seen}")
        if line.startswith(READY_PREFIX):
            return line
        seen.append(line.rstrip())


@pytest.fixture(scope="module")
def daemon() -> Iterator[Daemon]:
    """``lasercal serve --dry-run`` on a free loopback port with a fresh data folder."""
    _require_chromium()
    with tempfile.TemporaryDirectory(prefix="lasercal-page-") as tmp:
        data_dir = Path(tmp) / "data"
        config = Path(tmp) / "daemon.toml"
        config.write_text('default_job = "job.toml"\n', encoding="utf-8")
        (Path(tmp) / "job.toml").write_text(TOLERANT_JOB, encoding="utf-8")
        process = subprocess.Popen(
            [sys.executable, "-m", "lasercal_hw.cli.main", "serve", "--dry-run", "--listen", "127.0.0.1:0",
             "--data-dir", str(data_dir), "--config", str(config)],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, text=True,
        )
        try:
            line = _ready_line(process)
            base_url = line[len(READY_PREFIX):].split()[0]
            yield Daemon(base_url, (data_dir / "token").read_text(encoding="utf-8").strip(), data_dir)
        finally:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


@pytest.fixture(scope="module")
def browser(daemon: Daemon) -> Iterator[object]:
    """Headless Chromium with a fresh profile, through the system chromedriver."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

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
