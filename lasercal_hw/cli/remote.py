"""``lasercal remote``: drive a running daemon from a script or a shell (``calibrate``,
``verify``, ``status``, ``health``, ``jobs``, ``history``, ``activate``, ``mark-bad``, ``cancel``,
``resume``, ``diff``)."""

from __future__ import annotations

import json
import shlex
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from lasercal_hw.cli import remote_text
from lasercal_hw.errors import ConfigError, ExitCode

remote_app = typer.Typer(help="Talk to a running 'lasercal serve' daemon.", no_args_is_help=True)


def _daemon_url(url: str) -> str:
    """The ``--daemon`` option checked before anything is sent (exit 2 naming the option)."""
    from lasercal_hw.service.client import check_daemon_url

    try:
        return check_daemon_url(url)
    except ConfigError as exc:
        raise typer.BadParameter(str(exc)) from None


DaemonOption = Annotated[
    str,
    typer.Option(
        "--daemon",
        envvar="LASERCAL_DAEMON",
        callback=_daemon_url,
        help="Daemon URL (default http://127.0.0.1:8766).",
    ),
]
TokenFileOption = Annotated[
    Path | None,
    typer.Option(
        "--token-file",
        help="Token file (default: ~/.local/state/lasercal/token; $LASERCAL_TOKEN, the token itself, wins).",
    ),
]
JsonOption = Annotated[
    bool, typer.Option("--json", help="Print one JSON document (for scripts) instead of the text for people.")
]
ConfigOption = Annotated[Path | None, typer.Option("--config", help="Job file (TOML) to send.")]
WaitOption = Annotated[
    bool,
    typer.Option(
        "--wait",
        help="Follow the job to its end; exit code as 'lasercal run' (a verify: as 'lasercal verify', "
        "0 only when ok).",
    ),
]
YesOption = Annotated[bool, typer.Option("--yes", "-y", help="Confirm that the arm may move (required).")]
DwellOption = Annotated[float | None, typer.Option("--dwell", help="Dwell per waypoint in s.")]
PresetOption = Annotated[
    str | None, typer.Option("--preset", help="Trajectory preset (e.g. quick), over the job file's.")
]
DEFAULT_DAEMON = "http://127.0.0.1:8766"
_EXIT_BY_ERROR = {
    "invalid_job": ExitCode.BAD_INPUT,
    "device_error": ExitCode.DEVICE_ERROR,
    "protective_stop": ExitCode.DEVICE_ERROR,
    "calibration_failed": ExitCode.CALIBRATION_FAILED,
    "cancelled": ExitCode.INTERRUPTED,
    "interrupted": ExitCode.INTERRUPTED,
}


def _client(daemon: str, token_file: Path | None) -> Any:
    from lasercal_hw.service.client import DaemonClient, read_token

    return DaemonClient(daemon, read_token(token_file), token_file=token_file)


def _print(document: Any, as_json: bool, lines: list[str]) -> None:
    """The JSON document with ``--json``, else the lines a person reads."""
    if as_json:
        sys.stdout.write(json.dumps(document, indent=2) + "\n")
    else:
        sys.stdout.write("".join(f"{line}\n" for line in lines))


def _job_file(path: Path | None) -> dict[str, Any] | None:
    from lasercal_hw.config import read_job_file

    return None if path is None else read_job_file(path)


def _show_event(kind: str, data: dict[str, Any]) -> None:
    line = remote_text.event_line(kind, data)
    if line is not None:
        typer.echo(line, err=True)


def _finish(client: Any, job: dict[str, Any], as_json: bool) -> None:
    """Print a finished job and exit with the code 'lasercal run' (a verify: 'lasercal verify')
    would give."""
    document = job.get("document") or {}
    summary = document | {
        "job_id": job["id"],
        "state": job["state"],
        "calibration_id": job.get("calibration_id"),
        "verify_id": job.get("verify_id"),
        "error": job.get("error"),
    }
    # a cell job files one calibration per scanner (document["calibration_ids"]), each shown
    one = {"": job["calibration_id"]} if job.get("calibration_id") else {}
    ids = document.get("calibration_ids") or one
    calibrations = {} if as_json else {scanner: client.calibration(found) for scanner, found in ids.items()}
    _print(summary, as_json, remote_text.finished_job_lines(job, calibrations))
    if job["state"] == "succeeded":
        passed = bool((job.get("verdict") or {}).get("passed", True))
        raise typer.Exit(int(ExitCode.OK if passed else ExitCode.QUALITY_GATE_FAILED))
    code = (job.get("error") or {}).get("code", "")
    raise typer.Exit(int(_EXIT_BY_ERROR.get(code, ExitCode.DEVICE_ERROR)))


def _job(config: Path | None, preset: str | None) -> dict[str, Any] | None:
    """The job to send: the job file, with ``--preset`` over its trajectory preset."""
    job = _job_file(config)
    if preset is None:
        return job
    job = job or {}
    trajectory = {k: v for k, v in job.get("trajectory", {}).items() if k != "waypoints_file"}
    return job | {"trajectory": trajectory | {"preset": preset}}


def _motion_client(yes: bool, doing: str, daemon: str, token_file: Path | None) -> Any:
    """A client for a request that moves the arm, once ``--yes`` confirmed the motion."""
    if not yes:
        raise ConfigError(f"{doing} moves the arm: check the cell and pass --yes to confirm the motion")
    return _client(daemon, token_file)


def _print_or_follow(client: Any, job: dict[str, Any], wait: bool, as_json: bool) -> None:
    """Print the job as the daemon took it, or with ``--wait`` follow its events and exit
    with the code 'lasercal run' would give; Ctrl-C while following cancels the job (the
    arm stops) and exits 130, as Ctrl-C on 'lasercal run' does."""
    if not wait:
        follow = f"see how it goes with: lasercal remote jobs{_daemon_option(client)}"
        _print(job, as_json, [remote_text.job_line(job), follow])
        return
    try:
        finished = client.wait(job["id"], on_event=_show_event)
    except KeyboardInterrupt:
        typer.echo(cancel_after_interrupt(client, job["id"], job.get("kind")), err=True)
        raise typer.Exit(int(ExitCode.INTERRUPTED)) from None
    _finish(client, finished, as_json)


def _daemon_option(client: Any) -> str:
    """`` --daemon URL`` for a command shown to the user, or nothing for the default daemon."""
    return "" if client.url == DEFAULT_DAEMON else f" --daemon {shlex.quote(client.url)}"


def _token_options(client: Any) -> str:
    """``_daemon_option`` and `` --token-file PATH`` where the token was read from a named file:
    for a command shown to the user that needs the token."""
    named = "" if client.token_file is None else f" --token-file {shlex.quote(str(client.token_file))}"
    return _daemon_option(client) + named


def _send_motion(client: Any, send: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """The job a request that moves the arm started; a daemon busy with another job is one line
    naming that job and the commands to watch or cancel it (exit 5, ``ExitCode.BUSY``)."""
    from lasercal_hw.service.client import DaemonRequestError

    try:
        return send()
    except DaemonRequestError as exc:
        if exc.code != "job_running":
            raise
        running, kind = exc.detail.get("job_id", "?"), exc.detail.get("kind", "a job")
        daemon, token = _daemon_option(client), _token_options(client)
        raise DaemonRequestError(
            f"the daemon is busy: job {running} ({kind}) is moving the arm; watch it with: lasercal remote "
            f"status{daemon}, or cancel it with: lasercal remote cancel {running}{token}; then try again",
            status=exc.status, code=exc.code, detail=exc.detail,
        ) from None


def cancel_after_interrupt(client: Any, job_id: str, kind: str | None = None) -> str:
    """Cancel the job (of ``kind``) a Ctrl-C'd command was following; the one line that says what
    became of it and how to go on (a verify is started anew, not resumed)."""
    from lasercal_hw.service.client import DaemonRequestError

    daemon, token = _daemon_option(client), _token_options(client)
    try:
        client.cancel(job_id)
    except (DaemonRequestError, KeyboardInterrupt) as exc:
        if isinstance(exc, DaemonRequestError) and exc.code == "not_running":
            return f"interrupted: job {job_id} had already ended; see it with lasercal remote jobs{daemon}"
        why = str(exc) or "interrupted again"
        return (
            f"interrupted: the cancel of job {job_id} failed ({why}): job {job_id} may still be running; "
            f"stop it with: lasercal remote cancel {job_id}{token}"
        )
    go_on = (
        f"verify again with: lasercal remote verify --yes{token}"
        if kind == "verify"
        else f"continue with: lasercal remote resume {job_id} --yes{token}"
    )
    return f"interrupted: job {job_id} cancelled, the arm is being stopped (the recording is kept; {go_on})"


def _start(
    kind: str,
    daemon: str,
    token_file: Path | None,
    job: dict[str, Any] | None,
    dwell: float | None,
    yes: bool,
    wait: bool,
    as_json: bool,
    extra: dict[str, Any],
) -> None:
    client = _motion_client(yes, "this job", daemon, token_file)
    body = {"kind": kind, "confirm_motion": True, "job": job, "dwell_s": dwell} | extra
    started = _send_motion(client, lambda: client.start_job(body))
    if wait:
        typer.echo(f"job {started['id']} started; following its events", err=True)
    _print_or_follow(client, started, wait, as_json)


@remote_app.command("calibrate")
def calibrate_command(
    daemon: DaemonOption = DEFAULT_DAEMON,
    token_file: TokenFileOption = None,
    config: ConfigOption = None,
    preset: PresetOption = None,
    dwell: DwellOption = None,
    yes: YesOption = False,
    wait: WaitOption = False,
    as_json: JsonOption = False,
    dry_run: Annotated[
        bool, typer.Option("--dry-run", help="Run on a fake cell (job kind dry_run).")
    ] = False,
    activate: Annotated[
        bool, typer.Option("--activate", help="Make the result active if it passes.")
    ] = False,
    no_restore: Annotated[
        bool, typer.Option("--no-restore", help="Leave the robot's program unloaded.")
    ] = False,
) -> None:
    """Start a calibration (exit 5 when the daemon is busy with another job; with --wait: follow it
    and exit 0 passed, 1 gate failed, 2-4, 130)."""
    _start(
        "dry_run" if dry_run else "calibrate",
        daemon,
        token_file,
        _job(config, preset),
        dwell,
        yes,
        wait,
        as_json,
        {"activate_on_pass": activate, "restore_robot": not no_restore},
    )


@remote_app.command("verify")
def verify_command(
    daemon: DaemonOption = DEFAULT_DAEMON,
    token_file: TokenFileOption = None,
    yes: YesOption = False,
    wait: WaitOption = False,
    as_json: JsonOption = False,
) -> None:
    """Check the active calibration for drift (a verify job, with the job recorded with that
    calibration: its waypoints, dwell and [verify] table)."""
    _start("verify", daemon, token_file, None, None, yes, wait, as_json, {})


@remote_app.command("status")
def status_command(daemon: DaemonOption = DEFAULT_DAEMON, as_json: JsonOption = False) -> None:
    """Daemon, devices, active calibration and current job."""
    status = _client(daemon, None).status()
    _print(status, as_json, remote_text.status_lines(status))


@remote_app.command("health")
def health_command(daemon: DaemonOption = DEFAULT_DAEMON, as_json: JsonOption = False) -> None:
    """Every scanner's calibration: active, passed, age, last verify, robot calibration."""
    health = _client(daemon, None).health()
    _print(health, as_json, remote_text.health_lines(health))


@remote_app.command("jobs")
def jobs_command(daemon: DaemonOption = DEFAULT_DAEMON, as_json: JsonOption = False) -> None:
    """Jobs, newest first."""
    jobs = _client(daemon, None).jobs()
    if as_json:
        _print({"jobs": jobs}, True, [])
        return
    for job in jobs:
        typer.echo(
            f"{job['id']}  {job['kind']:<9} {job['state']:<11} {job['created_utc']}  "
            f"{job['progress']['message']}"
        )


@remote_app.command("history")
def history_command(daemon: DaemonOption = DEFAULT_DAEMON, as_json: JsonOption = False) -> None:
    """Calibrations, newest first (* marks the active one)."""
    calibrations = _client(daemon, None).calibrations()
    if as_json:
        _print({"calibrations": calibrations}, True, [])
        return
    for c in calibrations:
        t = ", ".join(f"{1000 * v:.1f}" for v in c["translation_m"])
        typer.echo(
            f"{'*' if c['active'] else ' '} {c['id']}  {'passed' if c['passed'] else 'FAILED'}  "
            f"{'dry run ' if c['dry_run'] else ''}t=({t}) mm  job {c['job_id']}"
        )


@remote_app.command("activate")
def activate_command(
    calibration_id: str,
    daemon: DaemonOption = DEFAULT_DAEMON,
    token_file: TokenFileOption = None,
    reason: Annotated[
        str, typer.Option("--reason", help="Why (kept in the activation log).")
    ] = "lasercal remote",
    force: Annotated[bool, typer.Option("--force", help="Activate even if it failed its gates.")] = False,
    as_json: JsonOption = False,
) -> None:
    """Make a calibration the active one (also how to roll back)."""
    summary = _client(daemon, token_file).activate(calibration_id, reason, force)
    lines = [f"active now: {calibration_id} ({reason})", *remote_text.calibration_lines(summary)]
    _print(summary, as_json, lines)


@remote_app.command("mark-bad")
def mark_bad_command(
    calibration_id: str,
    by: Annotated[str, typer.Option("--by", help="Who found it bad (a name or an address).")],
    reason: Annotated[str, typer.Option("--reason", help="Why it is bad (kept in the history).")],
    daemon: DaemonOption = DEFAULT_DAEMON,
    token_file: TokenFileOption = None,
    as_json: JsonOption = False,
) -> None:
    """Mark a calibration bad: it is never active again (the active one is deactivated)."""
    summary = _client(daemon, token_file).mark_bad(calibration_id, by, reason)
    bad = summary["bad"]
    lines = [f"marked bad: {calibration_id} by {bad['by']} at {bad['time_utc']} ({bad['reason']})"]
    _print(summary, as_json, lines)


@remote_app.command("cancel")
def cancel_command(
    job_id: str,
    daemon: DaemonOption = DEFAULT_DAEMON,
    token_file: TokenFileOption = None,
    as_json: JsonOption = False,
) -> None:
    """Stop a running job (the arm stops, the recording is kept)."""
    job = _client(daemon, token_file).cancel(job_id)
    lines = [f"cancel asked: {remote_text.job_line(job)}", "the arm stops; the recording is kept"]
    _print(job, as_json, lines)


@remote_app.command("resume")
def resume_command(
    job_id: str,
    daemon: DaemonOption = DEFAULT_DAEMON,
    token_file: TokenFileOption = None,
    yes: YesOption = False,
    wait: WaitOption = False,
    as_json: JsonOption = False,
) -> None:
    """Continue a cancelled or interrupted job from its recording."""
    client = _motion_client(yes, "resuming", daemon, token_file)
    _print_or_follow(client, _send_motion(client, lambda: client.resume(job_id)), wait, as_json)


@remote_app.command("diff")
def diff_command(a: str, b: str, daemon: DaemonOption = DEFAULT_DAEMON, as_json: JsonOption = False) -> None:
    """The change between two calibrations (mm, degrees) and whether it is significant."""
    diff = _client(daemon, None).diff(a, b)
    _print(diff, as_json, remote_text.diff_lines(diff, a, b))
