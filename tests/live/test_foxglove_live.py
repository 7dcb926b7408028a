"""The Foxglove live view over a real loopback websocket: a client subscribes as the app
does and receives the scan and the frames (the payloads are protobuf; the few fields the
tests read are decoded by hand)."""

from __future__ import annotations

import contextlib
import json
import math
import re
import signal
import socket
import struct
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("foxglove", reason="the foxglove extra is missing: pip install -e '.[foxglove]'")
websocket = pytest.importorskip("websocket", reason="websocket-client (comes with selenium) is missing")

from lasercal_hw.calibration.model import plane_crossing, rod_lines_in_base  # noqa: E402
from lasercal_hw.config import load_job  # noqa: E402
from lasercal_hw.geometry import (  # noqa: E402
    euler_zyx_to_matrix,
    make_transform,
    matrix_to_pose,
    quat_to_matrix,
    rotvec_to_matrix,
)
from lasercal_hw.live.foxglove import MIN_CENTRES_FOR_ESTIMATE, FoxgloveLiveView, RunGeometry  # noqa: E402
from lasercal_hw.models import RodLine  # noqa: E402
from lasercal_hw.run.cell import CellRunRequest  # noqa: E402
from lasercal_hw.run.events import RunEvent  # noqa: E402
from lasercal_hw.run.waypoints import job_waypoints  # noqa: E402
from tests.cli_helpers import assert_one_line_error, run_cli  # noqa: E402

SUBPROTOCOL = "foxglove.sdk.v1"
REPO = Path(__file__).parents[2]
LAYOUT = REPO / "docs" / "foxglove-layout.json"
CELL_LAYOUT = REPO / "docs" / "foxglove-layout-cell.json"
MESSAGE_DATA = 0x01
TIMEOUT_S = 10.0
SUBSCRIBE_POLL_S = 0.2


@pytest.fixture
def view() -> Iterator[FoxgloveLiveView]:
    live = FoxgloveLiveView(port=0)
    yield live
    live.close()


class Client:
    """A minimal Foxglove websocket client: the channels advertised, subscribe, receive."""

    def __init__(self, port: int, topics: tuple[str, ...] = ("/lasercal/log",)) -> None:
        self._ws = websocket.create_connection(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL],
                                               timeout=TIMEOUT_S)
        self.channels: dict[str, dict[str, Any]] = {}
        while not set(topics) <= set(self.channels):
            message = json.loads(self._ws.recv())
            if message["op"] == "advertise":
                self.channels.update({c["topic"]: c for c in message["channels"]})

    def subscribe(self, topic: str, subscription_id: int) -> None:
        channel_id = self.channels[topic]["id"]
        self._ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": subscription_id,
                                                                         "channelId": channel_id}]}))

    def first(self, subscription_id: int, publish: Callable[[], None]) -> bytes:
        """Publish until a message reaches the subscription (the server takes the subscribe
        asynchronously; what it publishes before then is not sent to this client)."""
        self._ws.settimeout(SUBSCRIBE_POLL_S)
        try:
            for _ in range(int(TIMEOUT_S / SUBSCRIBE_POLL_S)):
                publish()
                with contextlib.suppress(websocket.WebSocketTimeoutException):
                    return self.receive(subscription_id)
        finally:
            self._ws.settimeout(TIMEOUT_S)
        raise AssertionError(f"nothing reached subscription {subscription_id} within {TIMEOUT_S} s")

    def receive(self, subscription_id: int) -> bytes:
        """The payload of the next message on that subscription."""
        while True:
            frame = self._ws.recv()
            ours = isinstance(frame, bytes) and frame[0] == MESSAGE_DATA
            if ours and struct.unpack_from("<I", frame, 1)[0] == subscription_id:
                return frame[13:]

    def close(self) -> None:
        self._ws.close()


def _fields(payload: bytes) -> list[tuple[int, Any]]:
    """Protobuf fields (number, value): doubles for wire type 1, bytes for type 2."""
    fields, i = [], 0
    while i < len(payload):
        key, i = _varint(payload, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(payload, i)
        elif wire == 1:
            value, i = struct.unpack_from("<d", payload, i)[0], i + 8
        elif wire == 2:
            size, i = _varint(payload, i)
            value, i = payload[i:i + size], i + size
        else:
            raise AssertionError(f"unexpected wire type {wire}")
        fields.append((number, value))
    return fields


def _varint(payload: bytes, i: int) -> tuple[int, int]:
    value, shift = 0, 0
    while True:
        byte = payload[i]
        value |= (byte & 0x7F) << shift
        i, shift = i + 1, shift + 7
        if byte < 0x80:
            return value, i


def _transforms(payload: bytes) -> dict[tuple[str, str], np.ndarray]:
    """FrameTransforms -> {(parent, child): 4x4}."""
    found = {}
    for _, transform in _fields(payload):
        f = dict(_fields(transform))
        vector = dict(_fields(f.get(4, b"")))
        quaternion = dict(_fields(f.get(5, b"")))
        rotation = quat_to_matrix([quaternion.get(k, 0.0) for k in (1, 2, 3, 4)])
        translation = [vector.get(k, 0.0) for k in (1, 2, 3)]
        found[(f[2].decode(), f[3].decode())] = make_transform(rotation, translation)
    return found


def test_the_scan_channel_carries_each_averaged_scan(view: FoxgloveLiveView) -> None:
    client = Client(view.port)
    try:
        assert client.channels["/scan"]["schemaName"] == "foxglove.LaserScan"
        assert client.channels["/tf"]["schemaName"] == "foxglove.FrameTransforms"
        client.subscribe("/scan", 7)
        ranges = [1.25, None, 2.5, 3.0]
        scan = {"waypoint": 1, "angle_min_rad": -1.0, "angle_increment_rad": 0.5, "ranges_m": ranges,
                "rod_beams": [0], "circle": {"centre_uv_m": [1.0, 0.1], "radius_m": 0.02}}
        fields = _fields(client.first(7, lambda: view.on_event("scan", scan)))
    finally:
        client.close()
    layout = json.loads(LAYOUT.read_text(encoding="utf-8"))["configById"]
    shown = {t for panel in layout.values() for t in panel.get("topics", {})}
    shown |= {panel["topicToRender"] for panel in layout.values() if "topicToRender" in panel}
    assert shown <= set(client.channels), "docs/foxglove-layout.json shows topics the view does not serve"
    values = dict(fields)
    assert values[2] == b"laser"  # frame_id
    assert (values[4], values[5]) == (-1.0, 0.5)  # start and end angle: -1 + 3 * 0.5
    packed = values[6]  # repeated double ranges, packed; a missing return is NaN
    decoded = struct.unpack(f"<{len(ranges)}d", packed)
    assert decoded[0] == 1.25 and math.isnan(decoded[1]) and decoded[2:] == (2.5, 3.0)


def _scene(count: int) -> tuple[np.ndarray, np.ndarray, RodLine, np.ndarray]:
    """A scanner pose, TCP poses whose rods cross its plane, the rod and the exact centres."""
    rng = np.random.default_rng(3)
    T = make_transform(euler_zyx_to_matrix(0.3, -0.1, 0.05), [0.6, -0.2, 0.4])
    rod = RodLine(origin_m=np.array([0.0, 0.0, 0.05]), direction=np.array([0.0, 0.0, 1.0]))
    tcp = []
    for _ in range(count):
        rotation = T[:3, :3] @ rotvec_to_matrix(rng.uniform(-0.5, 0.5, 3) * [1, 1, 0.2])
        crossing = T[:3, :3] @ [rng.uniform(0.3, 0.8), rng.uniform(-0.3, 0.3), 0.0] + T[:3, 3]
        tcp.append(make_transform(rotation, crossing - rotation @ [0, 0, 0.2]))
    poses = matrix_to_pose(np.array(tcp))
    origins, directions = rod_lines_in_base(poses, rod)
    centres, _, _ = plane_crossing(T[:3, :3], T[:3, 3], origins, directions)
    return T, poses, rod, centres


def test_frames_show_the_tcp_the_rod_and_the_scanner_estimate(view: FoxgloveLiveView) -> None:
    T, poses, rod, centres = _scene(MIN_CENTRES_FOR_ESTIMATE + 2)
    view.begin(RunGeometry(poses, rod))
    client = Client(view.port)
    try:
        client.subscribe("/tf", 3)
        moving = {"stage": "move", "waypoint": 0}
        first = _transforms(client.first(3, lambda: view.on_event("progress", moving)))
        assert set(first) == {("base", "tcp"), ("tcp", "rod")}
        frames = {}
        for waypoint, centre in enumerate(centres):
            view.on_event("centre", {"waypoint": waypoint, "centre_uv_m": centre.tolist()})
            frames = _transforms(client.receive(3))
            if waypoint < MIN_CENTRES_FOR_ESTIMATE - 1:
                assert ("base", "laser") not in frames  # no nominal mounting and too few centres yet
        shifted = T.copy()
        shifted[:3, 3] += 0.001
        view.on_event("result", {"passed": True, "T_base_laser": shifted.tolist()})
        solved = _transforms(client.receive(3))
    finally:
        client.close()
    np.testing.assert_allclose(frames[("base", "tcp")][:3, 3], poses[-1][:3], atol=1e-9)
    np.testing.assert_allclose(frames[("tcp", "rod")][:3, 3], rod.origin_m, atol=1e-9)
    np.testing.assert_allclose(frames[("base", "laser")], T, atol=1e-6)  # closed form on exact centres
    np.testing.assert_allclose(solved[("base", "laser")][:3, 3], T[:3, 3] + 0.001, atol=1e-9)


def test_a_cell_shows_every_scanner_in_its_own_frame(view: FoxgloveLiveView, tmp_path: Path) -> None:
    """A cell job (examples/cell.toml): each scanner's scans on its own topic in its frame
    laser_NAME, and every scanner's frame in /tf from the start (its nominal mounting)."""
    job = load_job(REPO / "examples" / "cell.toml")
    events: list[Any] = []
    watch = view.watch_cell(CellRunRequest(job=job, out_dir=tmp_path), events.append)
    front_poses = job_waypoints(job.for_scanner("front"))
    client = Client(view.port, topics=("/lasercal/log", "/scan/front", "/scan/rear"))
    try:
        assert "/scan" in client.channels  # a one-scanner run's topic stays
        client.subscribe("/tf", 1)
        client.subscribe("/scan/rear", 2)
        client.subscribe("/scan/front", 3)
        moving = RunEvent(1, "progress", "move", {"stage": "move", "waypoint": 2, "scanner": "front"})
        frames = _transforms(client.first(1, lambda: watch(moving)))
        scan = {"waypoint": 0, "angle_min_rad": -1.0, "angle_increment_rad": 0.5, "ranges_m": [1.0, 2.0],
                "rod_beams": [], "circle": None}
        def scan_of(name: str) -> Callable[[], None]:
            return lambda: watch(RunEvent(2, "scan", "", scan | {"scanner": name}))

        rear_scan = dict(_fields(client.first(2, scan_of("rear"))))
        front_scan = dict(_fields(client.first(3, scan_of("front"))))
        solved = make_transform(np.eye(3), [-0.45, -0.40, 0.30])
        watch(RunEvent(4, "result", "", {"passed": True, "T_base_laser": solved.tolist(), "scanner": "rear"}))
        after = _transforms(client.receive(1))
    finally:
        client.close()
    assert {event.kind for event in events} == {"progress", "scan", "result"}, "the run's callback gets them"
    assert (rear_scan[2], front_scan[2]) == (b"laser_rear", b"laser_front")
    np.testing.assert_allclose(frames[("base", "tcp")][:3, 3], front_poses[2][:3], atol=1e-9)
    for name in ("front", "rear"):
        nominal = job.scanners[name].nominal
        assert nominal is not None
        np.testing.assert_allclose(frames[("base", f"laser_{name}")], nominal.matrix(), atol=1e-6)
    np.testing.assert_allclose(after[("base", "laser_rear")], solved, atol=1e-9)
    np.testing.assert_allclose(after[("base", "laser_front")], frames[("base", "laser_front")], atol=1e-9)
    assert ("base", "laser") not in after
    layout = json.loads(CELL_LAYOUT.read_text(encoding="utf-8"))["configById"]
    shown = {t for panel in layout.values() for t in panel.get("topics", {})}
    assert {"/scan/front", "/scan/rear"} <= shown <= set(client.channels), "the cell layout's topics"
    followed = {panel["followTf"] for panel in layout.values() if panel.get("followMode") == "follow-pose"}
    assert followed == {"laser_front", "laser_rear"} and followed <= {child for _, child in after}


@pytest.mark.parametrize("command", [
    ("run", "--dry-run", "--yes"),
    ("run", "--dry-run", "--yes", "--config", str(REPO / "examples" / "cell.toml"),
     "--scene", str(REPO / "fakes" / "scenes" / "two_scanners.toml")),
    ("serve", "--dry-run"),
])
def test_run_and_serve_say_when_the_foxglove_port_is_taken(command: tuple[str, ...]) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = run_cli(*command, "--foxglove", "--foxglove-port", str(port), timeout_s=60)
    assert_one_line_error(result, 2, f"127.0.0.1:{port}", "--foxglove-port")


@pytest.mark.timeout(180)
@pytest.mark.parametrize("command", [
    ("run", "--dry-run", "--yes", "--out"),
    ("serve", "--dry-run", "--listen", "127.0.0.1:0", "--data-dir"),
])
def test_run_and_serve_print_the_live_views_address_once(command: tuple[str, ...], tmp_path: Path) -> None:
    """The ws:// address a user pastes into Foxglove: printed once, with the port really bound
    (given as 0 here: only the line can tell it), on stdout like the other startup lines."""
    process = subprocess.Popen(
        [sys.executable, "-m", "lasercal_hw.cli.main", *command, str(tmp_path / "out"),
         "--foxglove", "--foxglove-port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
    )
    assert process.stdout is not None
    try:
        seen: list[str] = []
        while not any("ws://" in line for line in seen) and (line := process.stdout.readline()):
            seen.append(line)
        found = re.search(r"Foxglove live view on ws://127\.0\.0\.1:(\d+) ", "".join(seen))
        assert found is not None, "".join(seen)
        Client(int(found[1])).close()  # the address is the live view's
    finally:
        process.send_signal(signal.SIGINT)
        out, _err = process.communicate(timeout=60)
    assert "".join([*seen, out]).count("ws://") == 1
