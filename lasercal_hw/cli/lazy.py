"""A command group that lists its sub-commands by name and imports one only when it runs.

``lasercal --help`` needs each sub-command's name and one line of help, not its code; importing
every command module up front (scipy, matplotlib, ...) made every invocation wait over a
second. The group holds a placeholder per :class:`LazyCommand` for the help listing and swaps
in the real command, built by typer as ``app.command`` / ``app.add_typer`` would build it,
once the command line names it.
"""

from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass
from typing import Any, ClassVar, cast

import typer
from typer.core import TyperCommand, TyperGroup


@dataclass(frozen=True)
class LazyCommand:
    """A sub-command known by where it lives and what it does, until it runs."""

    target: str
    """``package.module:attribute`` of a command function or of a ``typer.Typer`` group."""
    help: str
    """One line for the listing (and the group's own help when the target is a group)."""

    def load(self, name: str) -> TyperCommand | TyperGroup:
        """Import the target and build its command under ``name``."""
        module_name, _, attribute = self.target.partition(":")
        target = getattr(importlib.import_module(module_name), attribute)
        shell = typer.Typer(add_completion=False)
        if isinstance(target, typer.Typer):
            shell.add_typer(target, name=name, help=self.help)
            group = cast(TyperGroup, typer.main.get_command(shell))
            return cast(TyperGroup, group.commands[name])
        shell.command(name, short_help=self.help)(target)
        return cast(TyperCommand, typer.main.get_command(shell))


def reflow_help(command: Any) -> None:
    """Join each help paragraph of ``command`` and its sub-commands into one line, so the help
    wraps to the terminal: typer's rich help keeps a docstring's single line breaks after its
    first paragraph and wraps those lines again, into jagged ones. A line that starts with
    ``- `` or with spaces (a list, an example) stays a line of its own."""
    if command.help:
        command.help = "\n\n".join(_joined(p) for p in inspect.cleandoc(command.help).split("\n\n"))
    for sub in getattr(command, "commands", {}).values():
        reflow_help(sub)


def _joined(paragraph: str) -> str:
    lines: list[str] = []
    for line in paragraph.split("\n"):
        if lines and not line.startswith(("- ", " ", "\b")) and not lines[-1].startswith("\b"):
            lines[-1] += " " + line
        else:
            lines.append(line)
    return "\n".join(lines)


class _Placeholder(TyperCommand):
    """Stands for a lazy command in listings; never invoked."""

    def __init__(self, name: str, lazy: LazyCommand) -> None:
        super().__init__(name, short_help=lazy.help)
        self.lazy = lazy


class LazyGroup(TyperGroup):
    """A typer group whose ``lazy_commands`` are imported when invoked (subclass to fill it)."""

    lazy_commands: ClassVar[dict[str, LazyCommand]] = {}

    def __init__(self, **attrs: Any) -> None:
        super().__init__(**attrs)
        for name, lazy in self.lazy_commands.items():
            self.commands.setdefault(name, _Placeholder(name, lazy))

    def resolve_command(self, ctx: Any, args: list[str]) -> tuple[str | None, Any, list[str]]:
        """Resolve as typer does, then replace a placeholder by its real command."""
        name, command, rest = super().resolve_command(ctx, args)
        if name is not None and isinstance(command, _Placeholder):
            command = command.lazy.load(name)
            reflow_help(command)
            self.commands[name] = command
        return name, command, rest
