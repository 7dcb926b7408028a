"""A recording's beam angles: each LaserScan's angle_min and angle_increment must agree with
the beam layout its scan_info states, or the recording is refused (a replay never places
the beams where they were not)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lasercal_hw.errors import ConfigError
from lasercal_hw.session.format import TOPIC_SCAN_INFO
from lasercal_hw.session.reader import read_session
from tests.recorder_helpers import make_scan
from tests.run.test_replay import CLUSTER_2_FROM_90, _copy
from tests.session.test_recorder import _record


def _with_scan_info_first_step(first_step: int):
    def change(topic: str, data: bytes) -> bytes:
        if topic != TOPIC_SCAN_INFO:
            return data
        info = json.loads(data)
        info["geometry"]["first_step"] = first_step
        return json.dumps(info).encode()

    return change


def test_angles_agreeing_with_the_layout_are_read(tmp_path: Path) -> None:
    path = tmp_path / "session.mcap"
    _record(path, [make_scan(1, geometry=CLUSTER_2_FROM_90)])
    assert read_session(path).scans[0].geometry == CLUSTER_2_FROM_90


def test_a_scan_info_contradicting_its_laser_scan_is_a_one_line_error(tmp_path: Path) -> None:
    path = tmp_path / "session.mcap"
    scan = make_scan(1)
    _record(path, [scan])
    edited = _copy(path, tmp_path / "edited.mcap", _with_scan_info_first_step(scan.geometry.first_step + 90))
    contradiction = r"scan 1's LaserScan says angle_min .* contradicts itself"
    with pytest.raises(ConfigError, match=contradiction) as caught:
        read_session(edited)
    assert "\n" not in str(caught.value)
