"""``lasercal scanner ...``: talk to a Hokuyo SCIP 2.0 scanner (real or fake)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import typer
from rich.table import Table

from drivers.hokuyo.client import HokuyoScanner
from lasercal_hw.cli.common import console, print_json
from lasercal_hw.errors import ConfigError
from lasercal_hw.models import LaserScan, ScanGeometry

scanner_app = typer.Typer(no_args_is_help=True)  # its help is in cli/main.py, where it is listed

URL_HELP = "Scanner URL: scip+tcp://HOST[:PORT] (port 10940) or scip+serial:///dev/ttyACM0[?baud=115200]."


def _fields_doc(value: Any, *, drop: tuple[str, ...] = (), add: tuple[str, ...] = ()) -> dict[str, Any]:
    """A dataclass as a JSON-ready dict: its fields except ``drop``, then the properties ``add``."""
    document = {f.name: getattr(value, f.name) for f in dataclasses.fields(value) if f.name not in drop}
    return document | {name: getattr(value, name) for name in add}


def _geometry_doc(geometry: ScanGeometry) -> dict[str, Any]:
    angles = geometry.angles_rad()
    return {
        "first_step": geometry.first_step,
        "last_step": geometry.last_step,
        "cluster": geometry.cluster,
        "beam_count": geometry.beam_count,
        "first_angle_rad": float(angles[0]),
        "last_angle_rad": float(angles[-1]),
        "min_range_m": geometry.min_range_m,
        "max_range_m": geometry.max_range_m,
    }


def _scan_doc(scan: LaserScan) -> dict[str, Any]:
    return {
        "sequence": scan.sequence,
        "device_time_s": scan.device_time_s,
        "host_time_s": scan.host_time_s,
        "ranges_m": [None if math.isnan(r) else r for r in scan.ranges_m.tolist()],
        "raw_ranges_mm": scan.raw_ranges_mm.tolist(),
        "intensities": None if scan.intensities is None else scan.intensities.tolist(),
    }


def _check_timeout(timeout_s: float) -> None:
    if not timeout_s > 0:
        raise ConfigError(f"--timeout must be a positive number of seconds, got {timeout_s:g}")


def _key_value_table(title: str, rows: dict[str, Any]) -> Table:
    table = Table(title=title, show_header=False, title_justify="left")
    table.add_column(style="bold")
    table.add_column()
    for key, value in rows.items():
        table.add_row(key, str(value))
    return table


@scanner_app.command("info")
def info(
    url: str = typer.Argument(..., help=URL_HELP),
    json_output: bool = typer.Option(False, "--json", help="Print one JSON document."),
    timeout_s: float = typer.Option(2.0, "--timeout", help="Reply timeout per command (s)."),
) -> None:
    """Identity (VV), parameters (PP) and status (II) of a scanner."""
    _check_timeout(timeout_s)
    with HokuyoScanner.open(url, timeout_s=timeout_s, sync_clock=False, reconnect=False) as scanner:
        identity, parameters, status = scanner.identity(), scanner.parameters(), scanner.status()
    document = {
        "url": url,
        "identity": _fields_doc(identity),
        "parameters": _fields_doc(parameters, drop=("raw",), add=("scan_period_s",)),
        "status": _fields_doc(status, drop=("model", "raw"), add=("healthy",)),
    }
    if json_output:
        print_json(document)
        return
    console.print(_key_value_table(f"Scanner {url}", document["identity"]))
    console.print(_key_value_table("Parameters (PP)", document["parameters"]))
    console.print(_key_value_table("Status (II)", document["status"]))


@scanner_app.command("capture")
def capture(
    url: str = typer.Argument(..., help=URL_HELP),
    scans: int = typer.Option(10, "--scans", "-n", help="Number of scans to capture."),
    intensity: bool = typer.Option(False, "--intensity", help="Stream with intensities (ME)."),
    json_output: bool = typer.Option(False, "--json", help="Print one JSON document with all ranges."),
    timeout_s: float = typer.Option(2.0, "--timeout", help="Reply and per-scan timeout (s)."),
) -> None:
    """Stream N scans (MD, or ME with --intensity) and summarise them."""
    if scans < 1:
        raise ConfigError(f"--scans must be at least 1, got {scans}")
    _check_timeout(timeout_s)
    captured: list[LaserScan] = []
    with HokuyoScanner.open(url, timeout_s=timeout_s) as scanner:
        geometry = scanner.geometry()
        scanner.start_streaming(intensities=intensity)
        while len(captured) < scans:
            captured.append(scanner.next_scan(timeout_s))
        scanner.stop_streaming()
        stats = scanner.stream_stats()
        identity = scanner.identity()
    # saved: the scans kept (the stream also receives those that come before QT is answered)
    stats_doc = {
        "saved": len(captured),
        "dropped": stats.queue_overflows + stats.corrupted,
        "queue_overflows": stats.queue_overflows,
        "corrupted": stats.corrupted,
        "reconnects": stats.reconnects,
        "missed_in_gaps": stats.missed_in_gaps,
    }
    if json_output:
        print_json(
            {
                "url": url,
                "identity": _fields_doc(identity),
                "geometry": _geometry_doc(geometry),
                "stats": stats_doc,
                "scans": [_scan_doc(scan) for scan in captured],
            }
        )
        return
    table = Table(
        title=f"{len(captured)} scans from {url} ({identity.model}, {geometry.beam_count} beams)",
        title_justify="left",
    )
    for column in ("seq", "t [s]", "lag [ms]", "valid", "min [m]", "median [m]", "max [m]"):
        table.add_column(column, justify="right")
    if intensity:
        table.add_column("intensity", justify="right")
    start_s = captured[0].device_time_s
    for scan in captured:
        valid = scan.ranges_m[scan.valid]
        summary = (
            [f"{np.min(valid):.3f}", f"{np.median(valid):.3f}", f"{np.max(valid):.3f}"]
            if valid.size
            else ["-", "-", "-"]
        )
        row = [
            str(scan.sequence),
            f"{scan.device_time_s - start_s:.3f}",
            f"{1000 * (scan.host_time_s - scan.device_time_s):.1f}",
            f"{valid.size}",
            *summary,
        ]
        if intensity and scan.intensities is not None:
            row.append(f"{np.median(scan.intensities):.0f}")
        table.add_row(*row)
    console.print(table)
    console.print(
        "t: scan time (device clock) since the first scan; lag: host receive time - scan time; "
        "intensity: median"
    )
    console.print(", ".join(f"{key} {value}" for key, value in stats_doc.items()))
