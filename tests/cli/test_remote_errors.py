"""``lasercal remote`` refuses a bad option before it sends anything: one line, exit 2."""

from __future__ import annotations

import pytest

from lasercal_hw.errors import ConfigError
from lasercal_hw.service.client import DaemonClient
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
