"""``lasercal scanner info|capture`` end to end against the fake scanner."""

from __future__ import annotations

import json
import socket
from collections.abc import Iterator

import pytest

from drivers.hokuyo.client import HokuyoScanner
from fakes.scip_server import FakeScannerServer
from tests.cli_helpers import assert_one_line_error, run_cli

pytestmark = [pytest.mark.integration, pytest.mark.timeout(90)]


@pytest.fixture(scope="module")
def url() -> Iterator[str]:
    with FakeScannerServer() as server:
        yield server.url


def test_info_json(url: str) -> None:
    result = run_cli("scanner", "info", url, "--json")
    assert result.returncode == 0, result.stderr
    document = json.loads(result.stdout)
    assert document["identity"]["model"] == "UTM-30LX-EW"
    assert document["parameters"]["max_range_mm"] == 60000
    assert document["status"]["healthy"] is True


def test_info_table(url: str) -> None:
    result = run_cli("scanner", "info", url)
    assert result.returncode == 0, result.stderr
    assert "UTM-30LX-EW" in result.stdout and "Parameters (PP)" in result.stdout


def test_capture_json_with_intensities(url: str) -> None:
    result = run_cli("scanner", "capture", url, "--scans", "5", "--intensity", "--json")
    assert result.returncode == 0, result.stderr
    document = json.loads(result.stdout)
    assert [scan["sequence"] for scan in document["scans"]] == [0, 1, 2, 3, 4]
    scan = document["scans"][0]
    assert len(scan["ranges_m"]) == len(scan["raw_ranges_mm"]) == len(scan["intensities"]) == 1081
    assert document["geometry"]["beam_count"] == 1081
    assert document["stats"]["dropped"] == 0


def test_capture_table(url: str) -> None:
    result = run_cli("scanner", "capture", url, "--scans", "3")
    assert result.returncode == 0, result.stderr
    assert "3 scans from" in result.stdout and "median" in result.stdout


def test_capture_counts_the_scans_it_saved_not_the_stream_messages(url: str) -> None:
    """The stream goes on until QT is answered, so a scan more than asked for usually arrives;
    the count is of the scans kept (the rows, the JSON's scans), not of what came."""
    document = json.loads(run_cli("scanner", "capture", url, "--scans", "5", "--json").stdout)
    assert len(document["scans"]) == document["stats"]["saved"] == 5
    assert "received" not in document["stats"]
    table = run_cli("scanner", "capture", url, "--scans", "5")
    assert table.returncode == 0, table.stderr
    assert "saved 5," in table.stdout and "received" not in table.stdout


def test_a_busy_scanner_is_named_busy_not_reset(url: str) -> None:
    """A UTM-30LX-EW serves one TCP client; the fake closes a second connection at once,
    which the second client sees as a reset or EOF. It is told the scanner is busy."""
    with HokuyoScanner.open(url, sync_clock=False) as first:
        first.start_streaming()
        first.next_scan(2.0)
        for command in (("scanner", "info", url), ("scanner", "capture", url, "--scans", "2")):
            assert_one_line_error(
                run_cli(*command), 3, url, "busy with another client", "one TCP client at a time",
                "stop the other client",
            )


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_connection_refused_is_one_clear_line() -> None:
    url = f"scip+tcp://127.0.0.1:{free_port()}"
    result = run_cli("scanner", "info", url)
    assert result.returncode == 3
    assert result.stderr.strip().count("\n") == 0
    assert f"cannot connect to {url}" in result.stderr
    assert "is the scanner powered and reachable?" in result.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("scanner", "info", "http://127.0.0.1"), "scip+tcp://HOST[:PORT]"),
        (("scanner", "info", "scip+serial:///dev/ttyACM0?speed=9"), "unknown option(s) speed"),
        (("scanner", "capture", "scip+tcp://127.0.0.1:1", "--scans", "0"), "--scans must be at least 1"),
        (("scanner", "info", "scip+tcp://[::1"), "Invalid IPv6 URL"),
        (("scanner", "info", "scip+tcp://127.0.0.1:1", "--timeout", "0"), "--timeout must be a positive"),
        (("scanner", "capture", "scip+tcp://127.0.0.1:1", "--timeout", "-1"), "--timeout must be a positive"),
    ],
)
def test_bad_input_exits_2_with_the_accepted_forms(args: tuple[str, ...], message: str) -> None:
    assert_one_line_error(run_cli(*args), 2, message)
