"""Surfaces of the fake world in the scanner frame: where a ray hits them and at what angle.

A ``Shape`` is a cylinder (rod, chuck, robot base), a rectangle (wall), a plane (floor)
or a twist drill (a prism whose section has two flutes and a web, turned along a helix).
``hit`` gives, for rays from ``origins`` (one point, or one per ray) along unit ``dirs``,
the distance to the first hit and the |cosine| of the incidence angle there;
``surface_hit`` adds how the surface's normal turns under a ray moved sideways (a curved
surface's glint is narrower than the gap between a beam's sub-rays: the scanner model
integrates its specular lobe over each sub-ray's strip of the spot with it).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from fakes.raycast import ray_cylinder, ray_plane, ray_rectangle
from lasercal_hw.models import FloatArray

_SECTION_VERTICES = 128
_FLUTE_HALF_OPENING_RAD = np.radians(50.0)
_LAND, _FLUTE, _FLAT = 0, 1, 2


class SurfaceHit(NamedTuple):
    """Per ray: distance to the first hit (inf: miss), |cos incidence| there (0 on a miss),
    and for a curved surface the section where its normal turns: |cos| of the incidence
    within that section (equal to ``cos`` on a flat surface) and how fast that angle turns
    per metre of sideways offset of the ray (rad/m; 0 on a flat surface or without
    ``lateral``)."""

    t: FloatArray
    cos: FloatArray
    section_cos: FloatArray
    turn_rad_per_m: FloatArray


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
        found = self.surface_hit(dirs, origins)
        return found.t, found.cos

    def surface_hit(
        self, dirs: FloatArray, origins: FloatArray | None = None, lateral: FloatArray | None = None
    ) -> SurfaceHit:
        """``hit`` plus the normal's turn under a ray moved along unit ``lateral`` (one
        vector, or one per ray): a cylinder's or a drill's section turns by ``1 / (radius of
        curvature · cos)`` per metre the ray moves across it; flat shapes do not turn."""
        origins = np.zeros(3) if origins is None else origins
        if self.kind == "drill":
            return _drill_hit(self, dirs, origins, lateral)
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
        if self.kind != "cylinder" or lateral is None or not hit.any():
            return SurfaceHit(t, cos, cos.copy(), np.zeros_like(cos))
        section_cos, turn = cos.copy(), np.zeros_like(cos)
        o = np.broadcast_to(origins, dirs.shape)[hit]
        side = np.broadcast_to(lateral, dirs.shape)[hit]
        on_side, side_cos, side_turn = self._cylinder_turn(dirs[hit], o + t[hit, None] * dirs[hit], side)
        section_cos[hit] = np.where(on_side, side_cos, cos[hit])
        turn[hit] = np.where(on_side, side_turn, 0.0)
        return SurfaceHit(t, cos, section_cos, turn)

    def _cylinder_turn(
        self, dirs: FloatArray, points: FloatArray, lateral: FloatArray
    ) -> tuple[NDArray[np.bool_], FloatArray, FloatArray]:
        """Hits on the side (not the flat end caps), the incidence within the cylinder's
        section (the plane across its axis) and the normal's turn per metre of sideways
        offset of the ray."""
        point, axis = self.params
        radius, s_min, s_max = self.scalars
        rel = points - point
        axial = rel @ axis
        on_cap = (np.abs(axial - s_min) < 1e-9) | (np.abs(axial - s_max) < 1e-9)
        radial = rel - axial[:, None] * axis
        normal = radial / np.fmax(np.linalg.norm(radial, axis=1), 1e-15)[:, None]
        d_section = dirs - (dirs @ axis)[:, None] * axis
        d_section /= np.fmax(np.linalg.norm(d_section, axis=1), 1e-15)[:, None]
        section_cos = np.abs(np.einsum("ij,ij->i", d_section, normal))
        across = np.cross(axis, d_section)
        offset_rate = np.abs(np.einsum("ij,ij->i", lateral, across))
        return ~on_cap, section_cos, section_turn(offset_rate, section_cos, radius)

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


def section_turn(
    offset_rate: FloatArray, section_cos: FloatArray, curvature_radius_m: float | FloatArray
) -> FloatArray:
    """How fast the incidence angle on a curved section turns (rad per metre of sideways
    ray offset): a ray moved by ``dp`` across a circle of radius ``rho`` meets it where the
    normal has turned by ``dp / (rho cos)``; ``offset_rate`` is how much of the sideways
    move lies across the ray within the section."""
    return offset_rate / (curvature_radius_m * np.fmax(section_cos, 1e-6))


def _flute_circle(web_fraction: float) -> tuple[float, float]:
    """Radius of a flute's circular arc and its centre's distance from the axis (for a
    drill of radius 1): the arc meets the outer circle 50 deg either side of the flute's
    middle and passes ``web_fraction`` (half the web over the radius) from the axis."""
    half_web = web_fraction  # web / diameter * (diameter / radius) / 2
    cos_a = np.cos(_FLUTE_HALF_OPENING_RAD)
    rho = (1.0 + half_web**2 - 2.0 * half_web * cos_a) / (2.0 * cos_a - 2.0 * half_web)
    return float(rho), float(rho + half_web)


@lru_cache(maxsize=16)
def drill_section(web_fraction: float) -> FloatArray:
    """Vertices (N, 2) of a twist drill's section for radius 1, counter-clockwise.

    Two lands of the outer circle and two flutes, each a circular arc opening 100 deg of
    the circumference, point-symmetric about the axis, leaving a web of ``web_fraction``
    of the diameter between them.  The section is star-shaped about the axis.
    """
    rho, centre_distance = _flute_circle(web_fraction)
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


def _drill_hit(
    shape: Shape, dirs: FloatArray, origins: FloatArray, lateral: FloatArray | None
) -> SurfaceHit:
    """Rays against the fluted prism: each ray is expressed in the section's 2D frame at
    the axial position where it passes the axis closest (the helix angle there), then
    intersected with the section polygon; the axial limits bound the hit.  The normal is
    the true arc's (a land's or a flute's), not the polygon edge's: a polished land's glint
    is narrower than the polygon's edges."""
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
    found = np.isfinite(t_best)
    q = o2 + np.where(found, t_best, 0.0)[:, None] * d2
    normal2, curvature_radius = _drill_normal(q, best, radius, web_fraction)
    d_in_plane = d2 / np.fmax(np.sqrt(d2_sq), 1e-15)[:, None]
    section_cos = np.abs(np.einsum("ij,ij->i", d_in_plane, normal2))
    cos = section_cos * np.sqrt(np.clip(d2_sq, 0.0, 1.0))
    turn = np.zeros_like(cos)
    if lateral is not None:
        side_dir = np.broadcast_to(lateral, dirs.shape)
        l2 = np.stack([side_dir @ ref, side_dir @ side], -1)
        l2 = np.stack([c * l2[:, 0] - s * l2[:, 1], s * l2[:, 0] + c * l2[:, 1]], -1)
        offset_rate = np.abs(l2[:, 0] * d_in_plane[:, 1] - l2[:, 1] * d_in_plane[:, 0])
        turn = section_turn(offset_rate, section_cos, curvature_radius)
    return SurfaceHit(
        t_best, np.where(found, cos, 0.0), np.where(found, section_cos, 0.0), np.where(found, turn, 0.0)
    )


def _drill_normal(
    q: FloatArray, edge_index: NDArray[np.int64], radius: float, web_fraction: float
) -> tuple[FloatArray, FloatArray]:
    """Unit normal (section frame) and radius of curvature (inf: flat) at section points
    ``q`` on the polygon edges ``edge_index``: the land's (outer circle's) or the flute's arc
    where both of the edge's ends lie on it, else the edge's own (where a flute meets a land)."""
    kind = _drill_edge_kinds(web_fraction)[edge_index]
    rho, centre_distance = _flute_circle(web_fraction)
    vertices = drill_section(web_fraction)
    edge = np.roll(vertices, -1, axis=0)[edge_index] - vertices[edge_index]
    centre = np.zeros_like(q)
    centre[:, 1] = np.where(q[:, 1] >= 0.0, centre_distance, -centre_distance) * radius
    flat_normal = np.stack([edge[:, 1], -edge[:, 0]], -1)
    normal = np.select([kind[:, None] == _LAND, kind[:, None] == _FLUTE], [q, centre - q], flat_normal)
    normal /= np.fmax(np.linalg.norm(normal, axis=1), 1e-15)[:, None]
    curvature = np.select([kind == _LAND, kind == _FLUTE], [radius, rho * radius], np.inf)
    return normal, curvature


@lru_cache(maxsize=16)
def _drill_edge_kinds(web_fraction: float) -> NDArray[np.int64]:
    """Each section edge's surface: a land, a flute, or flat (its ends on different arcs)."""
    on_land = np.abs(np.linalg.norm(drill_section(web_fraction), axis=1) - 1.0) < 1e-9
    after = np.roll(on_land, -1)
    return np.select([on_land & after, ~on_land & ~after], [_LAND, _FLUTE], _FLAT)
