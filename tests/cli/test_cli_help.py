"""Every command's ``--help`` as a person reads it: no ``<bool>`` after a flag, no word of an
option's help lost (rich markup eats ``[...]``), paragraphs that wrap to the terminal."""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import ClassVar

import click
import pytest
from typer.testing import CliRunner

from lasercal_hw.cli.lazy import reflow_help
from lasercal_hw.cli.main import _Commands, app

WIDE = 240


def _commands() -> Iterator[tuple[list[str], click.Command]]:
    """Every command and sub-command with the words that name it on the command line."""
    for name, lazy in _Commands.lazy_commands.items():
        command = lazy.load(name)
        reflow_help(command)
        yield [name], command
        for sub_name, sub in getattr(command, "commands", {}).items():
            yield [name, sub_name], sub


COMMANDS = list(_commands())


def _help(words: list[str], width: int = WIDE) -> str:
    result = CliRunner().invoke(app, [*words, "--help"], env={"COLUMNS": str(width)}, terminal_width=width)
    assert result.exit_code == 0, result.output
    return result.output


def _flat(text: str) -> str:
    """Text without box drawing and with all white space folded, for containment checks."""
    return re.sub(r"\s+", " ", re.sub(r"[│╭╮╰╯─]", " ", text)).strip()


@pytest.mark.parametrize(("words", "command"), COMMANDS, ids=[" ".join(w) for w, _ in COMMANDS])
def test_help_shows_every_word_and_no_bool_placeholder(words: list[str], command: click.Command) -> None:
    shown = _help(words)
    assert "<bool>" not in shown
    flat = _flat(shown)
    for param in command.params:
        text = getattr(param, "help", None)
        if text:
            assert _flat(text) in flat, f"{' '.join(words)} {param.name}: help text lost or cut: {text!r}"


def test_docstring_paragraphs_wrap_to_the_terminal() -> None:
    shown = _help(["run"], width=100)
    assert "4 calibration impossible (degenerate data)" in _flat(shown)
    lines = [line.rstrip() for line in shown.splitlines()]
    start = next(i for i, line in enumerate(lines) if line.strip().startswith("Exit codes:"))
    paragraph = lines[start:lines.index("", start) if "" in lines[start:] else None]
    # A re-wrapped docstring leaves short lines in the middle of a paragraph.
    assert all(len(line) > 80 for line in paragraph[:-1]), paragraph


def test_reflow_keeps_lists_and_joins_the_rest() -> None:
    class Command:
        help = (
            "First line\n    goes on.\n\n    A paragraph\n    on two lines.\n\n    - one item\n    - another"
        )
        commands: ClassVar[dict[str, object]] = {}

    command = Command()
    reflow_help(command)
    assert command.help == "First line goes on.\n\nA paragraph on two lines.\n\n- one item\n- another"
