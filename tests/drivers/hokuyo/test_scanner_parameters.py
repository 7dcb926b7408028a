"""VV/PP/II are checked like scan data (issue 14 item 1): a stale checksum is retried,
then refused naming the line; PP values must fit the model's data sheet."""

from __future__ import annotations

import re

import pytest

from drivers.hokuyo.client import PARAMETER_TRIES, HokuyoScanner
from drivers.hokuyo.info import parse_parameters
from fakes.scip_faults import ScipFaults
from fakes.scip_server import FakeScannerServer
from lasercal_hw.errors import ChecksumError, ProtocolError
from tests.cli_helpers import assert_one_line_error, run_cli

pytestmark = pytest.mark.timeout(60)

UTM_PP = {"MODL": "UTM-30LX-EW", "DMIN": "23", "DMAX": "60000", "ARES": "1440", "AMIN": "0",
          "AMAX": "1080", "AFRT": "540", "SCAN": "2400"}


def opened(server: FakeScannerServer) -> HokuyoScanner:
    return HokuyoScanner.open(server.url, sync_clock=False)


def test_stale_pp_checksum_on_every_reply_refuses_the_scanner_naming_the_line() -> None:
    with FakeScannerServer(faults=ScipFaults(stale_field="AFRT=560")) as server:
        with pytest.raises(ChecksumError) as caught:
            HokuyoScanner.open(server.url, sync_clock=False)
        assert server.stats.replies_sent >= 1 + PARAMETER_TRIES  # VV once, PP every try
    message = str(caught.value)
    assert "'AFRT:560;0'" in message and f"{PARAMETER_TRIES} times in a row" in message


def test_a_stale_reply_that_clears_on_a_retry_is_accepted() -> None:
    faults = ScipFaults(stale_field="AFRT=560", stale_replies=PARAMETER_TRIES - 1)
    with FakeScannerServer(faults=faults) as server, opened(server) as scanner:
        assert scanner.parameters().front_step == 540


def test_stale_vv_and_ii_lines_are_errors_too() -> None:
    stale_vv = FakeScannerServer(faults=ScipFaults(stale_field="SERI=H0123457"))
    with stale_vv, pytest.raises(ChecksumError, match="VV reply line 'SERI:H0123457;"):
        opened(stale_vv)
    stale_ii = FakeScannerServer(faults=ScipFaults(stale_field="STAT=Stable 000 no error!"))
    with stale_ii, opened(stale_ii) as scanner, pytest.raises(ChecksumError, match="II reply line 'STAT:"):
        scanner.status()


@pytest.mark.parametrize(("key", "value", "named"), [
    ("AFRT", "560", "AFRT 560 (a UTM-30LX has 540)"),
    ("ARES", "2048", "ARES 2048 (a UTM-30LX has 1440)"),
    ("AMAX", "1000", "AMAX 1000 (a UTM-30LX has 1080)"),
])
def test_pp_values_differing_from_the_models_data_sheet_are_refused(key: str, value: str, named: str) -> None:
    with pytest.raises(ProtocolError, match=re.escape(named)):
        parse_parameters({**UTM_PP, key: value})


def test_impossible_pp_values_of_an_unknown_model_are_refused() -> None:
    unknown = {**UTM_PP, "MODL": "UST-10LX", "AFRT": "1200"}
    with pytest.raises(ProtocolError, match="AFRT 1200 <= AMAX 1080"):
        parse_parameters(unknown)
    assert parse_parameters({**UTM_PP, "MODL": "UST-10LX", "AFRT": "600"}).front_step == 600


def test_scanner_info_refuses_a_stale_pp_checksum_with_one_line() -> None:
    with FakeScannerServer(faults=ScipFaults(stale_field="AFRT=560")) as server:
        result = run_cli("scanner", "info", server.url)
    assert_one_line_error(result, 3, "PP reply line 'AFRT:560;0' fails its checksum", "check the cable")
