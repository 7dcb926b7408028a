"""Every ``lasercal`` command line shown in the README and in docs/ names a real command and
real options with values of the right type (parsed by the CLI itself, not run: most need a
robot, a daemon or minutes of dry run; the README's quick start is run by CI's own checks).

Placeholders are read as a person fills them in: ``[--opt X]`` as ``--opt X``, a word in
capitals (``N``, ``HOST``, ``YAW``) or ``<job id>`` as the value ``4``, ``[...]``, shell
redirections and a trailing ``&`` left out."""

from __future__ import annotations

import re
import shlex
from pathlib import Path
from typing import Any

import pytest

from lasercal_hw.cli.main import _Commands

ROOT = Path(__file__).resolve().parents[2]
PROMPT = re.compile(
    r"^(?:\$ )?(?:(?:\.venv/bin/)?lasercal|(?:\.venv/bin/)?python -m lasercal_hw\.cli\.main) (?P<args>.*)$"
)
#: A command in an example job's comment: ``# Run:  lasercal run ...``, ``#   lasercal ...``.
COMMENTED = re.compile(r"#\s*(?:[A-Z][a-z ]*:)?\s*(?P<command>lasercal .*--.*)$")


def documented_commands() -> list[tuple[str, str]]:
    """(file:line, the arguments after ``lasercal``) of every command in a fenced block."""
    found = []
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        in_block, pending = False, ""
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if line.strip().startswith("```"):
                in_block, pending = not in_block, ""
                continue
            if not in_block:
                continue
            text = pending + line.strip()
            if text.endswith("\\"):
                pending = text[:-1] + " "
                continue
            pending = ""
            for part in re.split(r"\s*(?:&&|\|\|?|;)\s*", text):
                match = PROMPT.match(part.strip())
                if match:
                    found.append((f"{path.relative_to(ROOT)}:{number}", match["args"]))
    return found + commented_commands()


def commented_commands() -> list[tuple[str, str]]:
    """(file:line, the arguments after ``lasercal``) of every command in examples/' comments."""
    found = []
    for path in sorted((ROOT / "examples").rglob("*.toml")):
        pending: tuple[int, str] | None = None
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if pending is not None:
                start, text = pending
                text += " " + line.lstrip("# ").rstrip()
            else:
                match = COMMENTED.search(line)
                if match is None:
                    continue
                start, text = number, match["command"].rstrip()
            pending = (start, text[:-1]) if text.endswith("\\") else None
            if pending is None:
                found.append((f"{path.relative_to(ROOT)}:{start}", text.removeprefix("lasercal ")))
    return found


def as_filled_in(args: str) -> list[str]:
    """The words a person types for a documented command line."""
    args = re.sub(r"\s+#.*$", "", args)  # a comment
    args = re.sub(r"\s+\(.*\)$", "", args)  # a closing remark in parentheses
    args = re.sub(r"<[^>]+>", "4", args)
    args = args.replace("[...]", "")
    args = re.sub(r"[\[\]]", "", args)
    placeholder = re.compile(r"[A-Z][A-Z_]*")
    words = ["4" if placeholder.fullmatch(word) else word for word in shlex.split(args)]
    for stop in (">", "&", "2>"):
        if stop in words:
            words = words[: words.index(stop)]
    return words


COMMANDS = documented_commands()


def _parse(words: list[str]) -> None:
    """Parse ``words`` as ``lasercal`` would, without running the command."""
    name, *rest = words
    command: Any = _Commands.lazy_commands[name].load(name)
    path = [name]
    while hasattr(command, "commands") and rest and not rest[0].startswith("-"):
        path.append(rest[0])
        command = command.commands[rest.pop(0)]
    try:
        command.make_context(" ".join(path), rest)
    except Exception as exc:  # typer's own click: --help and the like end in Exit
        if type(exc).__name__ != "Exit":
            raise


def test_the_docs_show_commands() -> None:
    assert len(COMMANDS) >= 40  # the extraction itself works


@pytest.mark.parametrize(("where", "args"), COMMANDS, ids=[where for where, _ in COMMANDS])
def test_a_documented_command_parses(where: str, args: str) -> None:
    words = as_filled_in(args)
    assert words and words[0] in _Commands.lazy_commands, f"{where}: no such command: lasercal {args}"
    try:
        _parse(words)
    except KeyError as exc:
        pytest.fail(f"{where}: no sub-command {exc} in: lasercal {args}")
    except Exception as exc:
        message = exc.format_message() if hasattr(exc, "format_message") else str(exc)
        pytest.fail(f"{where}: lasercal {args}: {message}")


#: A python command that imports this project's code (a benchmark, the CLI, a driver).
PROJECT_PYTHON = re.compile(
    r"(?P<python>(?:\S*/)?python3?(?:\.\d+)?) (?:-m (?:benchmarks|lasercal_hw)\b"
    r"|-c [\"'].*\bfrom (?:benchmarks|drivers|fakes|lasercal_hw|trajectories)\b)"
)


def project_python_commands() -> list[tuple[str, str]]:
    """(file:line, interpreter) of every project-importing python command in a fenced block or
    an inline code span of the README and docs/."""
    found = []
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        in_block = False
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if line.strip().startswith("```"):
                in_block = not in_block
                continue
            for text in [line] if in_block else re.findall(r"`([^`]+)`", line):
                where = f"{path.relative_to(ROOT)}:{number}"
                found += [(where, match["python"]) for match in PROJECT_PYTHON.finditer(text)]
    return found


def test_documented_python_commands_use_the_projects_venv() -> None:
    """After the README's set-up the project's packages are in .venv alone: a bare `python` or
    `python3` running a benchmark or importing drivers/ is another interpreter, without numpy."""
    commands = project_python_commands()
    assert len(commands) >= 40  # the extraction itself works
    assert [(where, python) for where, python in commands if python != ".venv/bin/python"] == []
