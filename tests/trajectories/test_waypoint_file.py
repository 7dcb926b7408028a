"""Custom waypoint files: CSV and TOML, with errors that name the row/entry and field."""

from __future__ import annotations

from pathlib import Path

import pytest

from lasercal_hw.errors import ConfigError
from trajectories.waypoint import Waypoint
from trajectories.waypoint_file import (
    load_waypoints,
    parse_waypoints_csv,
    parse_waypoints_toml,
    waypoints_to_csv,
)

GOOD_CSV = """# two waypoints
index,x,y,z,rx,ry,rz
0, 0.45, -0.20, 0.35, 3.1416, 0.0, 0.0

1, 0.50, -0.10, 0.36, 3.0, 0.2, -0.1
"""


def test_csv_is_parsed_in_order_with_poses() -> None:
    waypoints = parse_waypoints_csv(GOOD_CSV)
    assert [w.index for w in waypoints] == [0, 1]
    assert waypoints[1].tcp_pose == (0.50, -0.10, 0.36, 3.0, 0.2, -0.1)


def test_csv_columns_may_come_in_any_order_with_a_label() -> None:
    text = "label,rz,ry,rx,z,y,x,index\nstart,0,0,3.14,0.3,0.1,0.4,7\n"
    (waypoint,) = parse_waypoints_csv(text)
    assert waypoint == Waypoint(index=7, tcp_pose=(0.4, 0.1, 0.3, 3.14, 0.0, 0.0), label="start")


def test_csv_round_trips_through_the_writer() -> None:
    original = [
        Waypoint(index=3, tcp_pose=(0.1234567890123, -0.2, 0.3, 3.0, 0.1, 0.2), label="a, with comma"),
        Waypoint(index=4, tcp_pose=(0.4, 0.5, 0.6, 0.0, 0.0, 1.0)),
    ]
    assert parse_waypoints_csv(waypoints_to_csv(original)) == original


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("index,x,y,z,rx,ry,rz\n0,0.4,0.1,abc,0,0,0\n", r"line 2: field 'z' is not a number: 'abc'"),
        ("index,x,y,z,rx,ry,rz\n0,0.4,0.1,0.3,0,0,0\n1,0.4,0.1,0.3,0,0\n", r"line 3: expected 7 fields"),
        ("index,x,y,z,rx,ry\n0,0.4,0.1,0.3,0,0\n", r"line 1: header .*missing rz"),
        ("index,x,y,z,rx,ry,rz,speed\n0,0.4,0.1,0.3,0,0,0,1\n", r"unknown speed"),
        ("index,x,y,z,rx,ry,rz\n0,0.4,0.1,0.3,0,0,nan\n", r"line 2: field 'rz' must be finite"),
        ("index,x,y,z,rx,ry,rz\n0,450,0.1,0.3,0,0,0\n", r"line 2: field 'x' = 450.0 m is implausibly far"),
        ("index,x,y,z,rx,ry,rz\n1.5,0.4,0.1,0.3,0,0,0\n", r"line 2: field 'index' must be a whole number"),
        ("index,x,y,z,rx,ry,rz\n-1,0.4,0.1,0.3,0,0,0\n", r"line 2: field 'index' must be a whole number"),
        (
            "index,x,y,z,rx,ry,rz\n2,0.4,0.1,0.3,0,0,0\n# c\n2,0.4,0.1,0.3,0,0,0\n",
            r"line 4: index 2 is already used by .*line 2",
        ),
        ("index,x,y,z,rx,ry,rz\n", r"no waypoints"),
        ("\n# nothing\n", r"the file is empty"),
    ],
)
def test_bad_csv_names_the_row_and_field(text: str, expected: str) -> None:
    with pytest.raises(ConfigError, match=expected):
        parse_waypoints_csv(text, source="my.csv")


def test_toml_with_and_without_indices() -> None:
    text = """
[[waypoints]]
pose = [0.45, -0.2, 0.35, 3.1416, 0.0, 0.0]
label = "first"

[[waypoints]]
index = 5
pose = [0.5, -0.1, 0.36, 3, 0.2, -0.1]
"""
    waypoints = parse_waypoints_toml(text)
    assert [(w.index, w.label) for w in waypoints] == [(0, "first"), (5, "")]
    assert waypoints[1].tcp_pose == (0.5, -0.1, 0.36, 3.0, 0.2, -0.1)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (
            "[[waypoints]]\npose = [0.4, 0.1, 0.3, 0, 0]\n",
            r"waypoints\[0\]: field 'pose' must be a list of 6",
        ),
        ("[[waypoints]]\nlabel = 'x'\n", r"waypoints\[0\]: field 'pose' is missing"),
        (
            "[[waypoints]]\npose = [0.4, 0.1, 0.3, 0, 0, 0]\n"
            "[[waypoints]]\npose = [0.4, 0.1, 'a', 0, 0, 0]\n",
            r"waypoints\[1\]: field 'pose.z' is not a number",
        ),
        (
            "[[waypoints]]\npose = [0.4, 0.1, 0.3, 0, 0, 0]\nspeed = 3\n",
            r"\[0\]: unknown field\(s\) speed",
        ),
        ("[[waypoints]]\npose = [0.4, 0.1, 0.3, 0, 0, true]\n", r"field 'pose.rz' must be a number"),
        ("[[waypoint]]\npose = [0.4, 0.1, 0.3, 0, 0, 0]\n", r"unknown top-level key\(s\) waypoint"),
        ("waypoints = 3\n", r"expected an array of tables"),
        ("[[waypoints]\n", r"not valid TOML"),
    ],
)
def test_bad_toml_names_the_entry_and_field(text: str, expected: str) -> None:
    with pytest.raises(ConfigError, match=expected):
        parse_waypoints_toml(text, source="my.toml")


def test_load_picks_the_format_from_the_suffix(tmp_path: Path) -> None:
    csv_file = tmp_path / "w.csv"
    csv_file.write_text(GOOD_CSV)
    toml_file = tmp_path / "w.toml"
    toml_file.write_text("[[waypoints]]\npose = [0.45, -0.2, 0.35, 3.1416, 0.0, 0.0]\n")
    assert len(load_waypoints(csv_file)) == 2
    assert len(load_waypoints(toml_file)) == 1
    with pytest.raises(ConfigError, match=r"w.csv line 3"):
        bad = tmp_path / "w.csv"
        bad.write_text("index,x,y,z,rx,ry,rz\n0,0,0,0,0,0,0\n0,0,0,0,0,0,0\n")
        load_waypoints(bad)


def test_load_rejects_missing_files_and_unknown_formats(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_waypoints(tmp_path / "nope.csv")
    other = tmp_path / "w.json"
    other.write_text("{}")
    with pytest.raises(ConfigError, match=r"unknown format '\.json'"):
        load_waypoints(other)
