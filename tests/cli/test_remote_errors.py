"""``lasercal remote`` refuses a bad option before it sends anything: one line, exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lasercal_hw.errors import ConfigError
from lasercal_hw.service.client import DaemonClient, read_token
from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon
from tests.cli_helpers import assert_one_line_error, run_cli
from tests.daemon_helpers import FakeEngine, fake_runners, served_in_thread


@pytest.mark.parametrize(
    ("daemon", "fragments"),
    [
        ("notaurl", ("--daemon", "'notaurl'", "http://127.0.0.1:8766")),
        ("127.0.0.1:8766", ("--daemon", "add http://", "http://127.0.0.1:8766")),
        ("ftp://127.0.0.1:8766", ("--daemon", "http://")),
        ("http://127.0.0.1:99999", ("--daemon", "port")),
    ],
)
def test_a_daemon_that_is_not_an_http_url_is_refused_up_front(
    daemon: str, fragments: tuple[str, ...]
) -> None:
    assert_one_line_error(run_cli("remote", "status", "--daemon", daemon), 2, *fragments)


def test_the_client_refuses_a_url_it_cannot_open() -> None:
    """A script that builds the client gets the same one-line error, never urllib's ValueError."""
    with pytest.raises(ConfigError, match="add http://"):
        DaemonClient("localhost:8766")


def test_a_token_file_that_does_not_exist_is_named_before_anything_is_sent(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Not a 401 from the daemon: no daemon listens at the URL, so only a check before the
    request can answer (exit 2 naming the file)."""
    monkeypatch.delenv("LASERCAL_TOKEN", raising=False)
    missing = tmp_path / "nope"
    result = run_cli("remote", "activate", "x", "--token-file", str(missing), "--daemon", "http://127.0.0.1:9")
    assert_one_line_error(result, 2, f"token file {missing} does not exist", "--token-file")
    with pytest.raises(ConfigError, match="does not exist"):
        read_token(missing)


def test_the_default_token_file_may_be_missing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Reading without a token (status, health) needs none: no default file is no token."""
    monkeypatch.delenv("LASERCAL_TOKEN", raising=False)
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    assert read_token(None) is None


@pytest.mark.parametrize("option", [("--dwell", "1"), ("--preset", "quick"), ("--config", "job.toml")])
def test_remote_verify_refuses_a_job_option_it_could_not_honour(option: tuple[str, str]) -> None:
    """A daemon's verify runs with the job recorded with the active calibration: a job, preset or
    dwell given to it is refused (a usage error, exit 2), not silently dropped."""
    result = run_cli("remote", "verify", *option, "--yes")
    assert result.returncode == 2 and "No such option" in result.stdout + result.stderr


CELL_JOB = Path(__file__).resolve().parents[2] / "examples" / "cell.toml"


def test_a_cell_daemon_refuses_a_preset_its_scanners_would_ignore(tmp_path: Path) -> None:
    """A cell's scanners each visit the waypoints of their own entry ([scanners.NAME.trajectory]);
    --preset sets the whole job's trajectory, which none of them would use: refused in one line
    saying where a cell's waypoints come from and how to give them, not silently dropped. The
    way it names (a scanner's own trajectory in the request) is taken."""
    config = load_daemon_config(None, {"data_dir": tmp_path / "data", "default_job": CELL_JOB})
    daemon = Daemon(config, runners=fake_runners(FakeEngine(waypoints=2)))
    env = {"LASERCAL_TOKEN": daemon.token}
    with served_in_thread(daemon) as url:
        refused = run_cli(
            "remote", "calibrate", "--dry-run", "--preset", "quick", "--yes", "--daemon", url, env=env
        )
        assert_one_line_error(
            refused, 2, "job.trajectory", "scanners front, rear", "[scanners.NAME.trajectory]", "--config",
        )
        assert DaemonClient(url, daemon.token).jobs() == []
        own = tmp_path / "front-quick.toml"
        own.write_text('[scanners.front.trajectory]\npreset = "quick"\n', encoding="utf-8")
        taken = run_cli("remote", "calibrate", "--dry-run", "--config", str(own), "--yes", "--json",
                        "--daemon", url, env=env)
        assert taken.returncode == 0, taken.stderr
        resolved = json.loads(taken.stdout)["request"]["resolved_job"]["scanners"]
        assert resolved["front"]["trajectory"]["preset"] == "quick"
        assert resolved["front"]["trajectory"]["waypoints_file"] is None
        assert resolved["rear"]["trajectory"]["waypoints_file"].endswith("rear-waypoints.csv")
        DaemonClient(url, daemon.token).wait(json.loads(taken.stdout)["id"])
