"""Suite-wide settings.

The suite runs on two xdist workers (``-n 2 --dist loadgroup``, the README's test command).
Modules whose fakes run in real time (a fake UR streaming RTDE at 500 Hz with the driver's
0.3 s stall watchdog, fake cells behind dry runs and daemons, a browser) are in one of two
groups, each group on one worker, one module after the other: so at most two real-time
modules run at once, one per core (a dry run takes about 0.85 of a core, no more than a
CPU-bound test beside it). The two groups hold about the same time; the CPU-bound rest fill
whichever worker is free. One group of them all took 12.6 min of the suite's 13 (issue 22
added the cell's page, kill and agreement tests). On 27 Nov 2026 (2 cores, nothing else
running): real_time_runs 377 s of test time, real_time_service 341 s, the rest 235 s; the
suite 8 min 14 s (9 min 33 s the same morning before the shorter dwells, verifies and dropped
report PNGs below), so the wall time is the sum over two (``--junitxml`` gives each test's time).
A real-time test is mostly the arm's moves (joint caps 1.5 rad/s, 4 rad/s^2), so time comes
back only by fewer runs, waypoints and dwell seconds: share a run between tests that read it
(module fixtures), give a dry run no more than its test checks (the daemon's quick job dwells
0.25 s, a verify of it visits 2 waypoints; no report PNG where no test reads one: rendering
one took 1.5-7 s beside the other worker).

The fake cell's scanner model is the physical UTM-30LX-EW by default (the user's, and the
README's dry run). The suite's dry runs use the ideal model (child processes inherit the
setting): they test the run, the service and the solver, and their accuracy bounds (a short
job's error against its std, the engine's run within 5 mm of the truth, the cell's 15 mm and
3 deg) were sized on the ideal model (exact rays plus the scene's ``[noise]``); the physical
model's footprint, material echoes, bias and drift would make them bounds on the extraction.
The physical model's extraction is tested on worlds built directly
(tests/scan/test_extraction_physical.py) and measured by benchmarks/extraction_physical.py.
"""

import os
from pathlib import Path

import pytest
from hypothesis import settings

from drivers.loopback import LOOPBACK_ONLY_ENV
from fakes.scene import MODEL_ENV

os.environ.setdefault(MODEL_ENV, "ideal")
os.environ[LOOPBACK_ONLY_ENV] = "the test suite"  # the drivers refuse any address off 127.0.0.0/8

# Hypothesis's 200 ms per-example deadline is a timing assertion: beside the real-time fakes on
# two cores it failed examples that are correct. The properties are what the suite asserts.
settings.register_profile("lasercal", deadline=None)
settings.load_profile("lasercal")

REAL_TIME_GROUPS: dict[str, frozenset[str]] = {
    # the daemon over HTTP and the page in a browser
    "real_time_service": frozenset(
        {
            "browser/test_cell_page.py",
            "browser/test_page.py",
            "cli/test_remote_output.py",
            "service/test_daemon_cell_kill.py",
            "service/test_data_folder_lock.py",
            "service/test_daemon_faults.py",
            "service/test_daemon_integration.py",
            "service/test_daemon_log.py",
            "service/test_health.py",
            "verify/test_verify_dry_run.py",
        }
    ),
    # runs from the command line, the drivers against their fakes
    "real_time_runs": frozenset(
        {
            "cli/test_cli_run.py",
            "cli/test_cli_trajectory.py",
            "drivers/hokuyo/test_scanner_contract.py",
            "drivers/ur/test_cli_ur.py",
            "drivers/ur/test_controller.py",
            "drivers/ur/test_fake_with_ur_rtde.py",
            "drivers/ur/test_primary.py",
            "drivers/ur/test_ur_client.py",
            "fakes/test_fake_scanner_e2e.py",
            "live/test_foxglove_live.py",
            "run/test_cell.py",
            "run/test_dry_run.py",
            "run/test_dry_run_robust.py",
            "run/test_engine.py",
        }
    ),
}
"""Test modules (relative to tests/) with real-time fakes, by xdist group: see the module docstring."""

REAL_TIME_MODULES = frozenset().union(*REAL_TIME_GROUPS.values())
"""Every real-time module, whichever its group."""

_TESTS = Path(__file__).parent


@pytest.hookimpl(tryfirst=True)  # before xdist reads the groups from the markers
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Put each real-time module into its xdist group (a no-op without ``--dist loadgroup``)."""
    group_of = {module: group for group, modules in REAL_TIME_GROUPS.items() for module in modules}
    for item in items:
        group = group_of.get(item.path.relative_to(_TESTS).as_posix())
        if group is not None:
            item.add_marker(pytest.mark.xdist_group(group))
