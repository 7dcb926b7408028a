"""Entry point of the ``lasercal`` command: registers the sub-commands and maps errors
to exit codes with a one-line message (``--debug`` shows the traceback)."""

from __future__ import annotations

import logging
import sys
import traceback

import typer
from rich.markup import escape
from typer.exceptions import TyperException

from lasercal_hw import __version__
from lasercal_hw.cli.common import err_console
from lasercal_hw.cli.fake import fake_app
from lasercal_hw.cli.remote import remote_app
from lasercal_hw.cli.robot import robot_app
from lasercal_hw.cli.run import run_command
from lasercal_hw.cli.scanner import scanner_app
from lasercal_hw.cli.serve import serve_command
from lasercal_hw.cli.session import session_app
from lasercal_hw.cli.simulate import simulate_command
from lasercal_hw.cli.solve import solve_command
from lasercal_hw.cli.trajectory import trajectory_app
from lasercal_hw.errors import ExitCode, LasercalError

app = typer.Typer(
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


app.command("simulate")(simulate_command)
app.command("solve")(solve_command)
app.command("run")(run_command)
app.add_typer(fake_app, name="fake")
app.add_typer(scanner_app, name="scanner")
app.add_typer(session_app, name="session")
app.add_typer(trajectory_app, name="trajectory")
app.add_typer(robot_app, name="robot")
app.command("serve")(serve_command)  # cli/serve.py and cli/remote.py import their libraries when run
app.add_typer(remote_app, name="remote")


def main() -> None:
    """Run the CLI; expected failures become one line on stderr and an exit code."""
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
