"""``lasercal session ...``: inspect and repair run recordings (session.mcap)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape

from lasercal_hw.cli.common import console, print_json
from lasercal_hw.config import DEFAULT_SCANNER_NAME
from lasercal_hw.session.reader import SessionRecording, read_session
from lasercal_hw.session.recorder import repair_session

session_app = typer.Typer(no_args_is_help=True)  # its help is in cli/main.py, where it is listed


def _summary(recording: SessionRecording, scanner: str | None = None) -> dict[str, Any]:
    """A recording's counts and dwell windows: one scanner's run (``--scanner``, or the one of a
    one-scanner recording), or a cell job's whole recording with each scanner's windows."""
    whole = scanner is None and recording.is_job_recording
    selected = recording if whole else recording.for_scanner(scanner)
    runs: dict[str | None, SessionRecording] = {None: selected}
    if whole:
        runs = {name: recording.for_scanner(name) for name in recording.scanner_names}
    scans = [s for each in recording.scans_by_scanner.values() for s in each] if whole else selected.scans
    times = [scan.host_time_s for scan in scans]
    windows = []
    for name, run in runs.items():
        for window in run.dwell_windows():
            windows.append(({} if name is None else {"scanner": name}) | {
                "index": window.index,
                "start_s": window.start_s,
                "end_s": window.end_s,
                "complete": window.complete,
                "scans": len(run.dwell_scans(window)),
                "tcp_pose": None if window.tcp_pose is None else window.tcp_pose.tolist(),
            })
    return {
        "path": str(recording.path),
        "truncated": recording.truncated,
        "truncation_reason": recording.truncation_reason,
        "job_recording": recording.is_job_recording,
        "scanners": recording.scanner_names,
        "scanner": None if whole else selected.scanner_names[0],
        "scans": len(scans),
        "watcher_scans": {} if whole else {name: len(s) for name, s in selected.scans_by_scanner.items()},
        "scans_by_scanner": {name: len(s) for name, s in recording.scans_by_scanner.items()} if whole else {},
        "scan_time_span_s": (max(times) - min(times)) if times else 0.0,
        "tcp_poses": len(recording.tcp_poses),
        "joint_states": len(recording.joint_states),
        "events": dict(Counter(str(event.get("kind")) for event in selected.events)),
        "meta_keys": sorted(selected.meta),
        "dwell_windows": windows,
    }


@session_app.command("info")
def info(
    path: Annotated[Path, typer.Argument(help="The session.mcap to read.")],
    json_output: Annotated[bool, typer.Option("--json", help="Print one JSON document.")] = False,
    scanner: Annotated[str | None, typer.Option(
        "--scanner", help="A cell job's recording: summarise this scanner's run (default: every scanner's)."
    )] = None,
) -> None:
    """Summarise a recording: counts, dwell windows, whether it was cut short; a cell job's one
    recording lists its scanners."""
    summary = _summary(read_session(path), scanner)
    if json_output:
        print_json(summary)
        return
    state = "closed cleanly"
    if summary["truncated"]:
        state = f"[yellow]truncated[/]: {escape(summary['truncation_reason'])}"
    console.print(f"{escape(summary['path'])}: {state}")
    if summary["scanner"] is None:  # a cell job's one recording (docs/recorder.md)
        console.print("a cell job's recording of scanners " + escape(", ".join(summary["scanners"])))
    elif summary["scanner"] != DEFAULT_SCANNER_NAME:
        console.print(f"scanner {escape(summary['scanner'])}'s run")
    for name, count in summary["scans_by_scanner"].items():
        console.print(f"scans of {escape(name)}: {count}")
    console.print(
        f"scans {summary['scans']} over {summary['scan_time_span_s']:.1f} s, "
        f"TCP poses {summary['tcp_poses']}, joint states {summary['joint_states']}"
    )
    for name, count in summary["watcher_scans"].items():  # a cell's other scanners (docs/cell.md)
        of = "" if summary["job_recording"] else ", watching"  # a job's: its own run's too
        console.print(f"scans of {escape(name)}{of}: {count}")
    console.print("events: " + (", ".join(f"{k} {n}" for k, n in summary["events"].items()) or "none"))
    console.print("meta: " + (", ".join(summary["meta_keys"]) or "none"))
    for window in summary["dwell_windows"]:
        span = (
            f"{window['end_s'] - window['start_s']:.2f} s, {window['scans']} scans"
            if window["complete"]
            else "incomplete"
        )
        of = f"{escape(window['scanner'])} " if "scanner" in window else ""
        console.print(f"  {of}waypoint {window['index']}: {span}")


@session_app.command("repair")
def repair(
    source: Annotated[Path, typer.Argument(help="A recording, possibly cut short by a crash.")],
    target: Annotated[Path, typer.Argument(help="New file to write (must not exist).")],
) -> None:
    """Copy the complete part of a recording into a closed, indexed MCAP file that every
    tool (Foxglove, ros2 bag) opens."""
    copied = repair_session(source, target)
    console.print(f"copied {copied} messages into {escape(str(target))}")
