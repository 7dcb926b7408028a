"""The dry run's scene follows the job: a scene file that gives the default scene the
job's rod, and a check that the fake cell holds the rod the job describes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from lasercal_hw.models import FloatArray, RodLine


def _toml_floats(values: FloatArray) -> str:
    """A TOML array of floats at full precision."""
    return "[" + ", ".join(repr(float(v)) for v in values) + "]"


def write_rod_scene(rod: RodLine, path: Path) -> Path:
    """A scene file that changes only the default scene's rod to ``rod`` (kept with the
    outputs, so the dry run can be repeated with ``--scene``)."""
    path.write_text(
        "# Written by `lasercal run --dry-run`: the default scene, holding the job's rod.\n"
        f"[rod]\norigin_m = {_toml_floats(rod.origin_m)}\ndirection = {_toml_floats(rod.direction)}\n"
        f"radius_m = {rod.radius_m!r}\nlength_m = {rod.length_m!r}\n",
        encoding="utf-8",
    )
    return path


def rods_differ(cell_rod: dict[str, Any] | None, rod: RodLine) -> str | None:
    """A warning when the fake cell's rod (from its ready line) is not the job's rod; a
    dry run only finds the rod the fake cell holds."""
    if cell_rod is None:
        return None
    direction = np.asarray(cell_rod["direction"], dtype=float)
    same = (
        np.allclose(cell_rod["origin_m"], rod.origin_m, atol=1e-3)
        and np.allclose(direction / np.linalg.norm(direction), rod.unit_direction(), atol=1e-3)
        and abs(cell_rod["radius_m"] - rod.radius_m) < 1e-4
    )
    if same:
        return None
    return (
        f"the fake cell's rod {cell_rod} differs from the job's rod; give the dry run a --scene whose "
        "[rod] matches the job (docs/extraction.md)"
    )
