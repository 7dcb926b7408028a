"""Entry point of the ``lasercal`` command: registers the sub-commands (each imported only
when it runs), limits BLAS threads, and maps errors to exit codes with a one-line message
(``--debug`` shows the traceback). Keep this module's imports light: no numpy, scipy or
matplotlib (tests/cli/test_cli_startup.py)."""

from __future__ import annotations

import logging
import sys
import traceback
from typing import ClassVar

import typer
from rich.markup import escape
from typer.exceptions import TyperException

from lasercal_hw import __version__
from lasercal_hw.cli.common import err_console
from lasercal_hw.cli.lazy import LazyCommand, LazyGroup
from lasercal_hw.cli.threads import limit_blas_threads
from lasercal_hw.errors import ExitCode, LasercalError


class _Commands(LazyGroup):
    """The sub-commands, in the order ``lasercal --help`` lists them. Each module is imported
    only when its command runs, so no command waits for another's imports (scipy, matplotlib)."""

    lazy_commands: ClassVar[dict[str, LazyCommand]] = {
        "simulate": LazyCommand(
            "lasercal_hw.cli.simulate:simulate_command",
            "Reproduce the paper's Table 1 by Monte Carlo and compare with the Cramér-Rao bound.",
        ),
        "solve": LazyCommand(
            "lasercal_hw.cli.solve:solve_command",
            "Solve for T_base_laser from observations.csv or from a run's session.mcap.",
        ),
        "run": LazyCommand(
            "lasercal_hw.cli.run:run_command",
            "Calibrate against the robot (or a fake cell with --dry-run) and write the results.",
        ),
        "verify": LazyCommand(
            "lasercal_hw.cli.verify:verify_command",
            "Check that the active calibration still holds: a few waypoints, a drift test, a verdict.",
        ),
        "fake": LazyCommand(
            "lasercal_hw.cli.fake:fake_app",
            "Run fake devices (scanner, robot) that speak the exact wire protocols, for dry runs and CI.",
        ),
        "scanner": LazyCommand(
            "lasercal_hw.cli.scanner:scanner_app",
            "Query a Hokuyo scanner and capture scans (SCIP 2.0 over TCP or serial).",
        ),
        "session": LazyCommand(
            "lasercal_hw.cli.session:session_app", "Inspect and repair session recordings (session.mcap)."
        ),
        "trajectory": LazyCommand(
            "lasercal_hw.cli.trajectory:trajectory_app",
            "List trajectory presets, show their waypoints, check waypoints offline, design them for a cell.",
        ),
        "robot": LazyCommand(
            "lasercal_hw.cli.robot:robot_app",
            "Talk to a UR robot (ur_rtde: dashboard, RTDE receive and control).",
        ),
        "serve": LazyCommand(
            "lasercal_hw.cli.serve:serve_command",
            "Run the calibration daemon (HTTP API on loopback; see docs/daemon.md).",
        ),
        "remote": LazyCommand(
            "lasercal_hw.cli.remote:remote_app", "Talk to a running 'lasercal serve' daemon."
        ),
    }


app = typer.Typer(
    cls=_Commands,
    name="lasercal",
    help="Calibrate a 2D laser scanner against a UR robot with a thin rod or a drill.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)

_debug = {"enabled": False}


def _version_callback(value: bool) -> None:
    if value:
        typer.echo(f"lasercal {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    debug: bool = typer.Option(False, "--debug", help="Show tracebacks and debug logs."),
    version: bool = typer.Option(
        False, "--version", callback=_version_callback, is_eager=True, help="Print the version."
    ),
) -> None:
    """lasercal: scanner-to-robot calibration."""
    _debug["enabled"] = debug
    logging.basicConfig(
        level=logging.DEBUG if debug else logging.WARNING,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )



def main() -> None:
    """Run the CLI; expected failures become one line on stderr and an exit code."""
    limit_blas_threads()  # before any command imports numpy or scipy
    try:
        exit_code = app(standalone_mode=False, prog_name="lasercal")
    except TyperException as exc:
        message = exc.format_message()
        ctx = getattr(exc, "ctx", None)
        if type(exc).__name__ != "NoArgsIsHelpError":  # typer has already shown the help for that one
            hint = f" (see '{ctx.command_path} --help')" if ctx is not None else ""
            err_console.print(f"[bold red]error:[/] {escape(message)}{escape(hint)}", soft_wrap=True)
        sys.exit(int(ExitCode.BAD_INPUT))
    except typer.Abort:
        err_console.print("aborted")
        sys.exit(int(ExitCode.INTERRUPTED))
    except LasercalError as exc:
        if _debug["enabled"]:
            traceback.print_exc()
        err_console.print(f"[bold red]error:[/] {escape(str(exc))}", soft_wrap=True)
        sys.exit(int(exc.exit_code))
    except KeyboardInterrupt:
        err_console.print("interrupted")
        sys.exit(int(ExitCode.INTERRUPTED))
    sys.exit(exit_code if isinstance(exit_code, int) else 0)


if __name__ == "__main__":
    main()
