"""Every benchmark command the README, docs/ and the benchmarks' own docstrings show names a
module that ``python -m`` runs from the repository root and options its parser accepts (parsed
by the benchmark's own ``argparse`` parser, which stops there: nothing is measured).

Placeholders are read as in tests/cli/test_docs_commands.py: ``[--opt X]`` as ``--opt X``, a
word in capitals or ``<...>`` as ``4``, ``[...]`` left out."""

from __future__ import annotations

import argparse
import importlib
import re
import shlex
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
COMMAND = re.compile(
    r"(?:\.venv/bin/)?python3?(?:\.\d+)? (?:-m benchmarks\.(?P<module>\w+)|(?P<script>benchmarks/\S+))"
)


def _blocks_and_prose(text: str) -> tuple[str, str]:
    """``text`` twice, same offsets: only its fenced blocks' lines, and only the rest (a Python
    file's docstrings count as both)."""
    block, prose, fenced = [], [], False
    for line in text.split("\n"):
        if line.strip().startswith("```"):
            fenced = not fenced
            line = " " * len(line)
        block.append(line if fenced else " " * len(line))
        prose.append(" " * len(line) if fenced else line)
    return "\n".join(block), "\n".join(prose)


def documented_commands() -> list[tuple[str, str]]:
    """(file:line, the command from ``python`` on) of every benchmark command: a line of a
    fenced block or of a docstring (with its continuation lines), or a span in backticks."""
    paths = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    found = set()
    for path in [*paths, *sorted((ROOT / "benchmarks").glob("*.py"))]:
        text = path.read_text(encoding="utf-8").replace("\\\n", "  ")  # a continued line, same offsets
        block, prose = _blocks_and_prose(text) if path.suffix == ".md" else (text, text)
        spans = [(m.start(1), m[1]) for m in re.finditer(r"`([^`]{1,400})`", prose)]
        lines = [(m.start(), m[0]) for m in re.finditer(r"^.*$", block, re.MULTILINE)]
        for start, candidate in spans + lines:
            candidate = " ".join(candidate.split()).removeprefix("Run: ").removeprefix("$ ").strip("`")
            if COMMAND.match(candidate):
                found.add((f"{path.relative_to(ROOT)}:{text.count(chr(10), 0, start) + 1}", candidate))
    return sorted(found)


def as_filled_in(command: str) -> list[str]:
    """The options a person types after the module's name."""
    args = COMMAND.sub("", command, count=1)
    args = re.sub(r"\s+#.*$", "", args)
    args = re.sub(r"\s+\(.*\)$", "", args)
    args = re.sub(r"<[^>]+>", "4", args)
    args = re.sub(r"\[?\.\.\.\]?", "", args)
    args = re.sub(r"[\[\]]", "", args)
    words = ["4" if re.fullmatch(r"[A-Z][A-Z_]*", word) else word for word in shlex.split(args)]
    for stop in (">", "&", "2>", "|"):
        if stop in words:
            words = words[: words.index(stop)]
    return words


COMMANDS = documented_commands()


class _StopAfterParsingError(Exception):
    """Raised by the patched parser once the options are parsed."""


def test_the_docs_show_benchmark_commands() -> None:
    assert len(COMMANDS) >= 60  # the extraction itself works
    assert any(where.startswith("benchmarks/") for where, _ in COMMANDS)


@pytest.mark.parametrize(("where", "command"), COMMANDS, ids=[where for where, _ in COMMANDS])
def test_a_documented_benchmark_command_parses(
    where: str, command: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    match = COMMAND.match(command)
    assert match is not None and match["module"], (
        f"{where}: {command}: run a benchmark as a module from the repository root "
        "(.venv/bin/python -m benchmarks.NAME): as a script it imports neither benchmarks.* nor tests.*"
    )
    module = importlib.import_module(f"benchmarks.{match['module']}")
    words = as_filled_in(command)
    if "argparse" not in Path(module.__file__ or "").read_text(encoding="utf-8"):
        assert not words, f"{where}: benchmarks.{match['module']} takes no options: {command}"
        return
    original = argparse.ArgumentParser.parse_args

    def parse_then_stop(self: argparse.ArgumentParser, *args: object, **kwargs: object) -> None:
        original(self, *args, **kwargs)  # type: ignore[arg-type]
        raise _StopAfterParsingError

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
    monkeypatch.setattr(sys, "argv", [f"{match['module']}.py", *words])
    with pytest.raises((_StopAfterParsingError, SystemExit)) as stopped:
        module.main()
    error = capsys.readouterr().err.strip().splitlines()[-1:]
    assert stopped.type is _StopAfterParsingError, f"{where}: {command}: {error}"
