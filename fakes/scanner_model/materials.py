"""How much of the laser each surface material sends back, by incidence angle.

A monostatic scanner sees a surface's diffuse part (Lambert: ``diffuse * cos``), its
specular part only near normal incidence (a lobe ``exp(-(angle / width)^2)``: for a
scanner whose emitter and receiver look the same way the half-angle vector is the beam
itself, so the lobe is the surface's microfacet slope distribution, Beckmann's
``exp(-tan^2 angle / m^2)`` with ``m`` the RMS slope, at small angles) and a
retro-reflector's return over a wide cone.  Diffuse 1.0 is the data sheet's white Kent
sheet (``matte``, white paper, 0.9 of it); docs/scanner-model.md gives every figure's source.

On a curved surface one sub-ray stands for a strip of the beam's spot, across which the
incidence angle turns; a polished surface's lobe can be narrower than that turn (a 10 mm
steel bit glints over 0.6 mm, the sub-rays are 1-2 mm apart), so each lobe is averaged
over the strip's angles in closed form (``_lobe_mean``) instead of read at its middle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import erfc

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


def backscatter(
    material: str,
    cos_incidence: FloatArray,
    section_cos: FloatArray | None = None,
    half_turn_rad: FloatArray | None = None,
) -> FloatArray:
    """Relative returned power per unit spot area for a surface hit at ``cos_incidence``.

    On a curved surface, ``section_cos`` is the incidence within the section where the
    normal turns and ``half_turn_rad`` how far it turns either side across the strip of
    the spot the value stands for: the lobes are then the strip's mean (the diffuse part
    is smooth and taken at the middle).  Without them the strip is flat.
    """
    optics = MATERIALS[material]
    cos = np.clip(np.asarray(cos_incidence, dtype=float), 0.0, 1.0)
    angle = np.arccos(cos)
    if section_cos is None or half_turn_rad is None:
        in_section, half_turn = angle, np.zeros_like(angle)
    else:
        in_section = np.arccos(np.clip(np.asarray(section_cos, dtype=float), cos, 1.0))
        half_turn = np.asarray(half_turn_rad, dtype=float)
    # The part of the incidence out of the section (a tilted cylinder) does not turn:
    # angle^2 = out^2 + in_section^2 at small angles (cos angle = cos out * cos in_section).
    out_sq = np.fmax(angle**2 - in_section**2, 0.0)
    value = optics.diffuse * cos
    if optics.specular:
        lobe = _lobe_mean(in_section, half_turn, optics.specular_width_rad)
        value = value + optics.specular * np.exp(-out_sq / optics.specular_width_rad**2) * lobe
    if optics.retro:
        lobe = _lobe_mean(in_section, half_turn, optics.retro_width_rad)
        value = value + optics.retro * np.exp(-out_sq / optics.retro_width_rad**2) * lobe
    return value


def _lobe_mean(angle_rad: FloatArray, half_turn_rad: FloatArray, width_rad: float) -> FloatArray:
    """Mean of ``exp(-(a / width)^2)`` over ``a`` in ``angle ± half_turn``: ``width sqrt(pi)
    / (4 half_turn) (erf((angle + half_turn) / width) - erf((angle - half_turn) / width))``,
    the lobe's own value where the strip hardly turns."""
    narrow = half_turn_rad < 1e-3 * width_rad
    half = np.where(narrow, 1.0, half_turn_rad)
    upper = (angle_rad + half) / width_rad
    lower = (angle_rad - half) / width_rad
    mean = width_rad * np.sqrt(np.pi) / (4.0 * half) * (erfc(lower) - erfc(upper))
    return np.where(narrow, np.exp(-((angle_rad / width_rad) ** 2)), mean)
