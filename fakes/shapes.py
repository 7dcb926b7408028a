"""Surfaces of the fake world in the scanner frame: where a ray hits them and at what angle.

A ``Shape`` is a cylinder (rod, chuck, robot base), a rectangle (wall), a plane (floor)
or a twist drill (a prism whose section has two flutes and a web, turned along a helix).
``hit`` gives, for rays from ``origins`` (one point, or one per ray) along unit ``dirs``,
the distance to the first hit and the |cosine| of the incidence angle there.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from fakes.raycast import ray_cylinder, ray_plane, ray_rectangle
from lasercal_hw.models import FloatArray

_SECTION_VERTICES = 128
_FLUTE_HALF_OPENING_RAD = np.radians(50.0)


@dataclass(frozen=True)
class Shape:
    """A surface in the scanner frame with what is needed to intersect and shade it.

    ``kind``: ``cylinder`` (params: axis point, unit axis; scalars: radius, s_min, s_max),
    ``rectangle`` (corner, edge u, edge v), ``plane`` (point, normal) or ``drill`` (axis
    point, unit axis, unit reference direction across the axis; scalars: radius, s_min,
    s_max, web fraction, helix lead).
    """

    kind: str
    params: tuple[FloatArray, ...]
    scalars: tuple[float, ...]
    reflectivity: float
    material: str = "matte"

    def moved(self, R: FloatArray, t: FloatArray) -> Shape:
        """The same shape with points mapped by ``R p + t`` and vectors by ``R v``."""
        if self.kind == "rectangle":
            corner, u, v = self.params
            params: tuple[FloatArray, ...] = (R @ corner + t, R @ u, R @ v)
        else:
            params = (R @ self.params[0] + t, *(R @ v for v in self.params[1:]))
        return Shape(self.kind, params, self.scalars, self.reflectivity, self.material)

    def intersect(self, dirs: FloatArray, origins: FloatArray | None = None) -> FloatArray:
        """Distance along each ray to its first hit (inf: miss)."""
        return self.hit(dirs, origins)[0]

    def hit(self, dirs: FloatArray, origins: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
        """Distance to the first hit (inf: miss) and |cos incidence| there (0 on a miss)."""
        origins = np.zeros(3) if origins is None else origins
        if self.kind == "drill":
            return _drill_hit(self, dirs, origins)
        if self.kind == "cylinder":
            point, axis = self.params
            radius, s_min, s_max = self.scalars
            t = ray_cylinder(origins, dirs, point, axis, radius, s_min, s_max)
        elif self.kind == "rectangle":
            t = ray_rectangle(origins, dirs, *self.params)
        else:
            t = ray_plane(origins, dirs, *self.params)
        cos = np.zeros(dirs.shape[0])
        hit = np.isfinite(t)
        if hit.any():
            o = np.broadcast_to(origins, dirs.shape)[hit]
            cos[hit] = self._cos_incidence(dirs[hit], o + t[hit, None] * dirs[hit])
        return t, cos

    def _cos_incidence(self, dirs: FloatArray, points: FloatArray) -> FloatArray:
        if self.kind == "cylinder":
            point, axis = self.params
            _, s_min, s_max = self.scalars
            rel = points - point
            axial = rel @ axis
            radial = rel - axial[:, None] * axis
            on_cap = (np.abs(axial - s_min) < 1e-9) | (np.abs(axial - s_max) < 1e-9)
            normal = np.where(
                on_cap[:, None], axis, radial / np.fmax(np.linalg.norm(radial, axis=1), 1e-15)[:, None]
            )
        elif self.kind == "rectangle":
            _, u, v = self.params
            normal = np.broadcast_to(np.cross(u, v) / np.linalg.norm(np.cross(u, v)), dirs.shape)
        else:
            normal = np.broadcast_to(self.params[1] / np.linalg.norm(self.params[1]), dirs.shape)
        return np.abs(np.einsum("ij,ij->i", dirs, normal))


@lru_cache(maxsize=16)
def drill_section(web_fraction: float) -> FloatArray:
    """Vertices (N, 2) of a twist drill's section for radius 1, counter-clockwise.

    Two lands of the outer circle and two flutes, each a circular arc opening 100 deg of
    the circumference, point-symmetric about the axis, leaving a web of ``web_fraction``
    of the diameter between them.  The section is star-shaped about the axis.
    """
    half_web = web_fraction  # web / diameter * (diameter / radius) / 2
    cos_a = np.cos(_FLUTE_HALF_OPENING_RAD)
    rho = (1.0 + half_web**2 - 2.0 * half_web * cos_a) / (2.0 * cos_a - 2.0 * half_web)
    centre_distance = rho + half_web
    psi = np.linspace(0.0, 2.0 * np.pi, _SECTION_VERTICES, endpoint=False)
    u = np.stack([np.cos(psi), np.sin(psi)], -1)
    radius = np.ones_like(psi)
    for sign in (1.0, -1.0):
        c = np.array([0.0, sign * centre_distance])
        along = u @ c
        disc = along**2 - c @ c + rho**2
        near = along - np.sqrt(np.fmax(disc, 0.0))
        radius = np.where((disc > 0.0) & (near > 0.0) & (near < radius), near, radius)
    return u * radius[:, None]


def _drill_hit(shape: Shape, dirs: FloatArray, origins: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Rays against the fluted prism: each ray is expressed in the section's 2D frame at
    the axial position where it passes the axis closest (the helix angle there), then
    intersected with the section polygon; the axial limits bound the hit."""
    point, axis, ref = shape.params
    radius, s_min, s_max, web_fraction, lead = shape.scalars
    side = np.cross(axis, ref)
    rel = np.broadcast_to(origins - point, dirs.shape)
    d_axial = dirs @ axis
    o_axial = rel @ axis
    o2 = np.stack([rel @ ref, rel @ side], -1)
    d2 = np.stack([dirs @ ref, dirs @ side], -1)
    d2_sq = np.einsum("ij,ij->i", d2, d2)
    t_closest = -np.einsum("ij,ij->i", o2, d2) / np.fmax(d2_sq, 1e-15)
    helix = 2.0 * np.pi * (o_axial + t_closest * d_axial) / lead
    c, s = np.cos(-helix), np.sin(-helix)
    o2 = np.stack([c * o2[:, 0] - s * o2[:, 1], s * o2[:, 0] + c * o2[:, 1]], -1)
    d2 = np.stack([c * d2[:, 0] - s * d2[:, 1], s * d2[:, 0] + c * d2[:, 1]], -1)
    vertices = drill_section(web_fraction) * radius
    a, edge = vertices, np.roll(vertices, -1, axis=0) - vertices
    # Solve o + t d = a + k e for every ray (rows) and edge (columns).
    denom = d2[:, None, 0] * edge[None, :, 1] - d2[:, None, 1] * edge[None, :, 0]
    w0 = a[None, :, 0] - o2[:, None, 0]
    w1 = a[None, :, 1] - o2[:, None, 1]
    safe = np.where(np.abs(denom) > 1e-15, denom, 1.0)
    t = (w0 * edge[None, :, 1] - w1 * edge[None, :, 0]) / safe
    k = (w0 * d2[:, None, 1] - w1 * d2[:, None, 0]) / safe
    ok = (np.abs(denom) > 1e-15) & (t > 0.0) & (k >= 0.0) & (k < 1.0)
    s_hit = o_axial[:, None] + t * d_axial[:, None]
    ok &= (s_hit >= s_min) & (s_hit <= s_max)
    t = np.where(ok, t, np.inf)
    best = np.argmin(t, axis=1)
    rows = np.arange(dirs.shape[0])
    t_best = t[rows, best]
    e = edge[best]
    normal2 = np.stack([e[:, 1], -e[:, 0]], -1) / np.fmax(np.linalg.norm(e, axis=1), 1e-15)[:, None]
    d_in_plane = d2 / np.fmax(np.sqrt(d2_sq), 1e-15)[:, None]
    cos = np.abs(np.einsum("ij,ij->i", d_in_plane, normal2)) * np.sqrt(np.clip(d2_sq, 0.0, 1.0))
    return t_best, np.where(np.isfinite(t_best), cos, 0.0)
