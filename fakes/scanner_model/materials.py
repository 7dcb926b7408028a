"""How much of the laser each surface material sends back, by incidence angle.

A monostatic scanner sees a surface's diffuse part (Lambert: ``diffuse * cos``), its
specular part only near normal incidence (a lobe ``exp(-(angle / width)^2)``) and a
retro-reflector's return over a wide cone.  ``matte`` with diffuse 1.0 is the data
sheet's white Kent sheet; docs/scanner-model.md gives every figure's source.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lasercal_hw.models import FloatArray


@dataclass(frozen=True)
class Optics:
    """Relative back-scatter of a material (white Kent sheet at normal incidence = 1)."""

    diffuse: float
    specular: float = 0.0
    specular_width_rad: float = 0.1
    retro: float = 0.0
    retro_width_rad: float = 0.6


MATERIALS: dict[str, Optics] = {
    "matte": Optics(diffuse=0.9),
    "painted": Optics(diffuse=0.5, specular=0.5, specular_width_rad=0.12),
    "bare_metal": Optics(diffuse=0.12, specular=4.0, specular_width_rad=0.10),
    "steel_drill": Optics(diffuse=0.06, specular=6.0, specular_width_rad=0.06),
    "retro_tape": Optics(diffuse=0.3, retro=300.0, retro_width_rad=0.7),
    "dark": Optics(diffuse=0.05),
}


def backscatter(material: str, cos_incidence: FloatArray) -> FloatArray:
    """Relative returned power per unit spot area for a surface hit at ``cos_incidence``."""
    optics = MATERIALS[material]
    cos = np.clip(np.asarray(cos_incidence, dtype=float), 0.0, 1.0)
    angle = np.arccos(cos)
    value = optics.diffuse * cos
    if optics.specular:
        value = value + optics.specular * np.exp(-((angle / optics.specular_width_rad) ** 2))
    if optics.retro:
        value = value + optics.retro * np.exp(-((angle / optics.retro_width_rad) ** 2))
    return value
