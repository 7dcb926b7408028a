"""The suite's own bookkeeping stays true to the files it names."""

from __future__ import annotations

from pathlib import Path

from tests.conftest import REAL_TIME_GROUPS, REAL_TIME_MODULES


def test_every_real_time_module_exists() -> None:
    """A renamed module would silently leave the real-time group and race its fakes."""
    tests = Path(__file__).parent
    missing = sorted(name for name in REAL_TIME_MODULES if not (tests / name).is_file())
    assert not missing, f"REAL_TIME_MODULES names modules that do not exist: {missing}"


def test_a_real_time_module_is_in_one_group() -> None:
    """A module in both groups would be split by xdist's grouping rules unpredictably."""
    counted = sum(len(modules) for modules in REAL_TIME_GROUPS.values())
    assert counted == len(REAL_TIME_MODULES), "a module is named in more than one real-time group"
