"""``lasercal remote`` refuses a bad option before it sends anything: one line, exit 2."""

from __future__ import annotations

from pathlib import Path

import pytest

from lasercal_hw.errors import ConfigError
from lasercal_hw.service.client import DaemonClient, read_token
from tests.cli_helpers import assert_one_line_error, run_cli


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
