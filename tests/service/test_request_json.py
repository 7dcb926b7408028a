"""A request body that is not JSON gets a 400 saying so and where, on every route that takes
a body, over real sockets (an in-process daemon served by uvicorn on a loopback port)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon
from tests.daemon_helpers import FakeEngine, fake_runners, served_in_thread

pytestmark = pytest.mark.timeout(60)

ROUTES_WITH_A_BODY = (
    "/v1/jobs",
    "/v1/jobs/job-x/resume",
    "/v1/calibrations/cal-x/activate",
    "/v1/calibrations/cal-x/mark-bad",
)


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[httpx.Client]:
    """A client with the token, of a daemon with a fake engine."""
    data_dir: Path = tmp_path_factory.mktemp("json") / "data"
    daemon = Daemon(load_daemon_config(None, {"data_dir": data_dir}), runners=fake_runners(FakeEngine()))
    with served_in_thread(daemon) as url, httpx.Client(base_url=url, timeout=10.0) as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        yield client


@pytest.mark.parametrize("path", ROUTES_WITH_A_BODY)
@pytest.mark.parametrize(
    ("body", "position"),
    [(b'{"kind":"dry_run","confirm_motion":tru', 35), (b'{"reason": "x"}{', 15), (b"\xff\xfe{}", 0)],
)
def test_a_body_that_is_not_json_is_a_400_naming_where(
    client: httpx.Client, path: str, body: bytes, position: int
) -> None:
    answer = client.post(path, content=body, headers={"Content-Type": "application/json"})
    assert answer.status_code == 400, answer.text
    problem = answer.json()
    assert problem["code"] == "invalid_json", problem
    assert "not valid JSON" in problem["message"] and f"character {position}" in problem["message"], problem
    assert problem["detail"] == {"position": position}, problem
