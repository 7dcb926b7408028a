"""Start-up of the command line: commands are imported when they run, BLAS runs one thread.

Behaviour, not timing (benchmarks/startup.py prints the times): which modules a fresh
interpreter has loaded, which environment the command sets.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from lasercal_hw.calibration.observations import write_observations_csv
from lasercal_hw.cli.main import _Commands
from lasercal_hw.cli.threads import BLAS_THREAD_VARIABLES
from tests.calibration.test_solver_helpers import observations
from tests.cli_helpers import run_cli

HEAVY = ("numpy", "scipy", "matplotlib", "pydantic")


def _python(code: str, env: dict[str, str] | None = None) -> str:
    """Run ``code`` in a fresh interpreter; its standard output."""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          stdin=subprocess.DEVNULL, env=env, check=False)
    assert done.returncode == 0, done.stderr
    return done.stdout


def _loaded(heavy: tuple[str, ...]) -> str:
    return f"import sys; print(json.dumps([m for m in {heavy!r} if m in sys.modules]))"


def test_importing_the_entry_point_loads_no_numpy_scipy_matplotlib() -> None:
    # numpy too: the BLAS thread limit is set in main(), so it must come before numpy loads
    assert json.loads(_python(f"import json, lasercal_hw.cli.main; {_loaded(HEAVY)}")) == []


def test_solving_a_csv_loads_neither_matplotlib_nor_scipy_stats(tmp_path: Path) -> None:
    path = tmp_path / "observations.csv"
    write_observations_csv(path, observations(points=20))
    code = (
        "import contextlib, io, json, sys\n"
        "from lasercal_hw.cli.main import app\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        f"    app(['solve', {str(path)!r}, '--json'], standalone_mode=False)\n"
        f"{_loaded(('scipy.optimize', 'matplotlib', 'scipy.stats', 'lasercal_hw.cli.run'))}"
    )
    assert json.loads(_python(code)) == ["scipy.optimize"]


def test_help_lists_every_command_with_its_line_and_each_one_loads() -> None:
    result = subprocess.run([sys.executable, "-m", "lasercal_hw.cli.main", "--help"], capture_output=True,
                            text=True, timeout=60, stdin=subprocess.DEVNULL,
                            env=os.environ | {"COLUMNS": "250"}, check=False)  # one line per command
    assert result.returncode == 0, result.stderr
    listing = " ".join(result.stdout.split())
    for name, lazy in _Commands.lazy_commands.items():
        assert f"{name} {lazy.help}" in listing
        assert lazy.load(name).name == name


def test_a_group_shows_its_help_and_a_command_runs_once_named() -> None:
    fake = run_cli("fake", "--help")
    assert fake.returncode == 0, fake.stderr
    assert _Commands.lazy_commands["fake"].help in " ".join(fake.stdout.split())
    assert "cell" in fake.stdout
    presets = run_cli("trajectory", "list", "--json")
    assert presets.returncode == 0, presets.stderr
    assert json.loads(presets.stdout)


def _threads_after_main(env: dict[str, str]) -> dict[str, str | None]:
    code = (
        "import json, os, sys\n"
        "from lasercal_hw.cli.main import main\n"
        "sys.argv = ['lasercal', '--version']\n"
        "try:\n    main()\nexcept SystemExit:\n    pass\n"
        f"print(json.dumps({{name: os.environ.get(name) for name in {BLAS_THREAD_VARIABLES!r}}}))"
    )
    return json.loads(_python(code, env).splitlines()[-1])


def test_the_command_runs_blas_on_one_thread_unless_the_user_says_otherwise() -> None:
    clean = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    assert _threads_after_main(clean) == dict.fromkeys(BLAS_THREAD_VARIABLES, "1")
    chosen = _threads_after_main(clean | {"OPENBLAS_NUM_THREADS": "4"})
    assert chosen["OPENBLAS_NUM_THREADS"] == "4"
    assert chosen["OMP_NUM_THREADS"] == "1"
