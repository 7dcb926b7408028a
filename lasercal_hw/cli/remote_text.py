"""What ``lasercal remote`` shows a person: the daemon's JSON documents as a few plain lines
each (the JSON itself only with ``--json``). Pure functions from a document to lines."""

from __future__ import annotations

from typing import Any

from lasercal_hw.config import DEFAULT_SCANNER_NAME

# The events a person follows with --wait: stages, one line per waypoint (its centre or its
# skip; the progress events of the same waypoint say the same again), and what went wrong.
FOLLOWED_KINDS = ("stage", "centre", "skip", "fault", "warning", "stopped", "result", "calibration")


def _yes_no(value: Any) -> str:
    return "unknown" if value is None else ("yes" if value else "no")


def _vector(values: list[float] | None, scale: float = 1.0, digits: int = 1) -> str:
    if not values:
        return "-"
    return "(" + ", ".join(f"{scale * v:.{digits}f}" for v in values) + ")"


def _largest(values: list[float] | None, digits: int) -> str:
    return "-" if not values else f"{max(values):.{digits}f}"


def _identity(identity: dict[str, Any]) -> str:
    return f"{identity.get('model', '')} serial {identity.get('serial', '?')}".strip()


def calibration_lines(summary: dict[str, Any], title: str = "calibration") -> list[str]:
    """A calibration (the daemon's summary or a run document): pose, std, verdict."""
    verdict = summary.get("verdict") or {}
    passed = summary.get("passed", verdict.get("passed"))
    name = f"{title} {summary['id']}" if summary.get("id") else title
    lines = [
        f"{name}: {'passed' if passed else 'FAILED its quality gates'}"
        + (" (dry run)" if summary.get("dry_run") else ""),
        f"  translation {_vector(summary.get('translation_m'), 1000.0)} mm, "
        f"euler zyx {_vector(summary.get('euler_zyx_deg'), 1.0, 3)} deg",
        f"  std (largest component) {_largest(summary.get('std_translation_mm'), 2)} mm, "
        f"{_largest(summary.get('std_rotation_deg'), 3)} deg; "
        f"rms residual {summary.get('rms_residual_mm', float('nan')):.2f} mm",
    ]
    error = (summary.get("ground_truth") or {}).get("error")
    if error:
        lines.append(
            f"  dry run: error against the fake cell's truth {error['translation_mm']:.2f} mm, "
            f"{error['rotation_deg']:.3f} deg"
        )
    lines += [
        f"  gate failed: {c['name']} {c['value']:.3g} {c['unit']} (limit {c['limit']:.3g})"
        for c in verdict.get("checks", [])
        if not c.get("passed", True)
    ]
    return lines


def job_line(job: dict[str, Any]) -> str:
    """One line: id, kind, state, and what it is doing or how it ended."""
    error = job.get("error") or {}
    if error:
        code, message = str(error.get("code")), str(error.get("message"))
        said = code == job["state"] or message.startswith(code)  # "interrupted, interrupted: ..."
        tail = message if said else f"{code}: {message}"
    else:
        tail = "" if job.get("finished_utc") else (job.get("progress") or {}).get("message") or ""
    new = tail and tail != job["state"]  # a queued job's progress says "queued" too
    return f"job {job['id']} ({job['kind']}): {job['state']}" + (f", {tail}" if new else "")


def finished_job_lines(job: dict[str, Any], calibrations: dict[str, dict[str, Any]]) -> list[str]:
    """A job at its end: its state, and the verify's verdict or the calibrations it produced
    (the daemon's summaries, by scanner; "" for a one-scanner job's, with a dry run's error
    against the truth)."""
    lines = [job_line(job)]
    verdict = job.get("verdict") or {}
    if job["kind"] == "verify" and "status" in verdict:
        lines.append(f"verify: {verdict['status'].upper()}: {verdict.get('reason', '')}")
        if job.get("verify_id"):
            lines.append(f"  filed as {job['verify_id']}")
        return lines
    truth = (job.get("document") or {}).get("ground_truth")
    for scanner, calibration in calibrations.items():
        if scanner:
            lines += calibration_lines(calibration, f"scanner {scanner}: calibration")
        else:
            lines += calibration_lines(calibration | ({"ground_truth": truth} if truth else {}))
    return lines


def status_lines(status: dict[str, Any]) -> list[str]:
    """``GET /v1/status`` for a person."""
    daemon = status["daemon"]
    robot = status.get("robot") or {}
    lines = [
        f"daemon: lasercal {daemon['version']}{' (dry run: a fake cell)' if daemon.get('dry_run') else ''}, "
        f"up since {daemon['started_utc']}, data in {daemon['data_dir']}",
        f"robot: {robot.get('host') or 'none configured'}, connected {_yes_no(robot.get('connected'))}, "
        f"mode {robot.get('mode') or '-'}, safety {robot.get('safety') or '-'}, "
        f"remote control {_yes_no(robot.get('remote_control'))}",
    ]
    if robot.get("error"):
        lines.append(f"  robot: {robot['error']}")
    for scanner in status.get("scanners") or [status.get("scanner") or {}]:  # a cell's, one line each
        name = scanner.get("name") or DEFAULT_SCANNER_NAME
        device = "scanner" if name == DEFAULT_SCANNER_NAME else f"scanner {name}"
        held = f", in use by {scanner['in_use_by_job']}" if scanner.get("in_use_by_job") else ""
        identity = f", {_identity(scanner['identity'])}" if scanner.get("identity") else ""
        url = scanner.get("url") or "none configured"
        lines.append(f"{device}: {url}, connected {_yes_no(scanner.get('connected'))}{held}{identity}")
        if scanner.get("error"):
            lines.append(f"  {device}: {scanner['error']}")
    active = status.get("active_calibration")
    lines += calibration_lines(active, "active calibration") if active else ["active calibration: none"]
    job = status.get("job")
    lines.append(job_line(job) if job else "job: none yet")
    return lines


def _age(age_s: float | None) -> str:
    """``3 min``, ``5.2 h``, ``12 d``."""
    if age_s is None:
        return "-"
    if age_s < 3600:
        return f"{age_s / 60:.0f} min"
    return f"{age_s / 3600:.1f} h" if age_s < 86400 else f"{age_s / 86400:.0f} d"


def health_lines(health: dict[str, Any]) -> list[str]:
    """One line per scanner: calibration, its age, the last verify, the robot's calibration."""
    lines = []
    for scanner in health["scanners"]:
        if not scanner["active_calibration"]:
            lines.append(f"{scanner['name']}: no active calibration")
            continue
        verify = scanner["last_verify"]
        verified = "never verified"
        if verify is not None:
            verified = f"verify {verify['verdict']} {_age(verify['age_s'])} ago"
        matches = scanner["robot_calibration_matches"]
        lines.append(
            f"{scanner['name']}: {scanner['calibration_id']} {'passed' if scanner['passed'] else 'FAILED'}, "
            f"{_age(scanner['age_s'])} old, {verified}; robot calibration matches: "
            f"{matches if matches == 'unknown' else _yes_no(matches)} ({scanner['robot_calibration_note']}); "
            f"range error: {scanner['range_error']['note']}"
        )
    return lines


def diff_lines(diff: dict[str, Any], a: str, b: str) -> list[str]:
    """``GET /v1/calibrations/{a}/diff/{b}`` for a person."""
    significant = diff["significant"]
    return [
        f"{b} against {a}:",
        f"  translation {_vector(diff['translation_mm'], 1.0, 2)} mm, |{diff['translation_norm_mm']:.2f}| mm "
        f"(combined std {_vector(diff['combined_std_translation_mm'], 1.0, 2)} mm)",
        f"  rotation {_vector(diff['rotation_deg'], 1.0, 3)} deg, |{diff['rotation_angle_deg']:.3f}| deg "
        f"(combined std {_vector(diff['combined_std_rotation_deg'], 1.0, 3)} deg)",
        "  significant: yes, some component above 3 combined std" if significant
        else "  significant: no, every component within 3 combined std",
    ]


def event_line(kind: str, data: dict[str, Any]) -> str | None:
    """The line a followed event prints (None: not shown)."""
    if kind == "state":
        error = data.get("error") or {}
        return f"[state] {data.get('state')}" + (f": {error.get('message')}" if error else "")
    if kind in FOLLOWED_KINDS and data.get("message"):
        return f"[{kind}] {data['message']}"
    return None
