"""Suite-wide settings.

The suite runs on two xdist workers (``-n 2 --dist loadgroup``, the README's test command).
Modules whose fakes run in real time (a fake UR streaming RTDE at 500 Hz with the driver's
0.3 s stall watchdog, fake cells behind dry runs and daemons, a browser) share one group and
so one worker, one after the other; the rest, CPU-bound, fill the other worker.

The fake cell's scanner model is the physical UTM-30LX-EW by default, on which today's rod
extraction does not yet hold (issue 18); dry runs in this suite test the run, the service
and the solver, so they use the ideal model (child processes inherit the setting).  Tests
of the physical model build their worlds directly.  Drop this when the extraction lands.
"""

import os
from pathlib import Path

import pytest

from fakes.scene import MODEL_ENV

os.environ.setdefault(MODEL_ENV, "ideal")

REAL_TIME_MODULES = frozenset(
    {
        "browser/test_cell_page.py",
        "browser/test_page.py",
        "cli/test_cli_run.py",
        "cli/test_cli_trajectory.py",
        "cli/test_remote_output.py",
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
        "service/test_daemon_cell_kill.py",
        "service/test_daemon_faults.py",
        "service/test_daemon_integration.py",
        "service/test_daemon_log.py",
        "service/test_health.py",
        "verify/test_verify_dry_run.py",
    }
)
"""Test modules (relative to tests/) kept on one worker: see the module docstring."""

_TESTS = Path(__file__).parent


@pytest.hookimpl(tryfirst=True)  # before xdist reads the groups from the markers
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Put the real-time modules into one xdist group (a no-op without ``--dist loadgroup``)."""
    for item in items:
        if item.path.relative_to(_TESTS).as_posix() in REAL_TIME_MODULES:
            item.add_marker(pytest.mark.xdist_group("real_time"))
