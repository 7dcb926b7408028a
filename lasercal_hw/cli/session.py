"""``lasercal session ...``: inspect and repair run recordings (session.mcap)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape

from lasercal_hw.cli.common import console, print_json
from lasercal_hw.session.reader import SessionRecording, read_session
from lasercal_hw.session.recorder import repair_session

session_app = typer.Typer(no_args_is_help=True)  # its help is in cli/main.py, where it is listed


def _summary(recording: SessionRecording) -> dict[str, Any]:
    times = [scan.host_time_s for scan in recording.scans]
    windows = []
    for window in recording.dwell_windows():
        scans = len(recording.dwell_scans(window))
        windows.append({
            "index": window.index,
            "start_s": window.start_s,
            "end_s": window.end_s,
            "complete": window.complete,
            "scans": scans,
            "tcp_pose": None if window.tcp_pose is None else window.tcp_pose.tolist(),
        })
    return {
        "path": str(recording.path),
        "truncated": recording.truncated,
        "truncation_reason": recording.truncation_reason,
        "scans": len(recording.scans),
        "watcher_scans": {name: len(scans) for name, scans in recording.scans_by_scanner.items()},
        "scan_time_span_s": (max(times) - min(times)) if times else 0.0,
        "tcp_poses": len(recording.tcp_poses),
        "joint_states": len(recording.joint_states),
        "events": dict(Counter(str(event.get("kind")) for event in recording.events)),
        "meta_keys": sorted(recording.meta),
        "dwell_windows": windows,
    }


@session_app.command("info")
def info(
    path: Annotated[Path, typer.Argument(help="The session.mcap to read.")],
    json_output: Annotated[bool, typer.Option("--json", help="Print one JSON document.")] = False,
) -> None:
    """Summarise a recording: counts, dwell windows, whether it was cut short."""
    summary = _summary(read_session(path))
    if json_output:
        print_json(summary)
        return
    state = "closed cleanly"
    if summary["truncated"]:
        state = f"[yellow]truncated[/]: {escape(summary['truncation_reason'])}"
    console.print(f"{escape(summary['path'])}: {state}")
    console.print(
        f"scans {summary['scans']} over {summary['scan_time_span_s']:.1f} s, "
        f"TCP poses {summary['tcp_poses']}, joint states {summary['joint_states']}"
    )
    for name, count in summary["watcher_scans"].items():  # a cell's other scanners (docs/cell.md)
        console.print(f"scans of {escape(name)}, watching: {count}")
    console.print("events: " + (", ".join(f"{k} {n}" for k, n in summary["events"].items()) or "none"))
    console.print("meta: " + (", ".join(summary["meta_keys"]) or "none"))
    for window in summary["dwell_windows"]:
        span = (
            f"{window['end_s'] - window['start_s']:.2f} s, {window['scans']} scans"
            if window["complete"]
            else "incomplete"
        )
        console.print(f"  waypoint {window['index']}: {span}")


@session_app.command("repair")
def repair(
    source: Annotated[Path, typer.Argument(help="A recording, possibly cut short by a crash.")],
    target: Annotated[Path, typer.Argument(help="New file to write (must not exist).")],
) -> None:
    """Copy the complete part of a recording into a closed, indexed MCAP file that every
    tool (Foxglove, ros2 bag) opens."""
    copied = repair_session(source, target)
    console.print(f"copied {copied} messages into {escape(str(target))}")
