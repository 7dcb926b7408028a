"""The dry run's scene follows the job: a scene file that gives the default scene the
job's rod, and a check that the fake cell holds the rod the job describes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from lasercal_hw.models import RodLine


def write_rod_scene(rod: RodLine, path: Path) -> Path:
    """A scene file: the default scene with its rod changed to ``rod`` (a fluted rod: a steel
    twist drill, without a chuck) kept with the outputs, so the dry run can be repeated with
    ``--scene``."""
    from fakes.scene import load_scene  # the dry-run step only: nothing else here needs a fake

    default = load_scene(None)
    as_drill = {"shape": "twist_drill", "material": "steel_drill"} if rod.fluted else {}
    rod_settings = default.rod.model_copy(
        update={
            "origin_m": [float(v) for v in rod.origin_m],
            "direction": [float(v) for v in rod.direction],
            "radius_m": float(rod.radius_m),
            "length_m": float(rod.length_m),
            **as_drill,
        }
    )
    scene = default.model_copy(update={"rod": rod_settings})
    header = "# Written by `lasercal run --dry-run`: the default scene, holding the job's rod.\n"
    path.write_text(header + scene.to_toml(), encoding="utf-8")
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
