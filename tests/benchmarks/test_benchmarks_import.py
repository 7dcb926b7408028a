"""Every benchmark the docs name still imports and runs from ``python -m``: a module renamed or
split under it (the solver and the extraction became packages) breaks a documented command
without failing any other test."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

#: Modules that other benchmarks import, with no command of their own.
SHARED = {"verify_trials", "waypoint_errors"}
BENCHMARKS = sorted(p.stem for p in (Path(__file__).parents[2] / "benchmarks").glob("*.py"))


def test_the_benchmarks_folder_is_found() -> None:
    assert len(BENCHMARKS) >= 20
    assert set(BENCHMARKS) >= SHARED


@pytest.mark.parametrize("name", BENCHMARKS)
def test_benchmark_imports(name: str) -> None:
    module = importlib.import_module(f"benchmarks.{name}")
    if name not in SHARED:
        assert callable(getattr(module, "main", None)), f"benchmarks/{name}.py has no main()"
