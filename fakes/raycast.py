"""Exact, vectorised ray intersections for the fake world (pure geometry, no state).

Rays start at ``origin_m`` (one common point (3,), or one point per ray (N, 3): a beam's
footprint is a bundle of parallel-offset rays) and run along unit vectors ``dirs`` (N, 3);
each function returns the distance ``t`` (N,) to the first hit in front of the origin, or
``inf`` where the ray misses.  All shapes are given in the frame of the rays.
"""

from __future__ import annotations

import numpy as np

from lasercal_hw.models import FloatArray

_EPS = 1e-12


def ray_cylinder(
    origin_m: FloatArray,
    dirs: FloatArray,
    axis_point_m: FloatArray,
    axis_dir: FloatArray,
    radius_m: float,
    s_min_m: float = -np.inf,
    s_max_m: float = np.inf,
) -> FloatArray:
    """Distance to a solid cylinder: side surface between axial limits, plus its end caps.

    The axis is ``axis_point_m + s * axis_dir`` (``axis_dir`` unit length) for ``s`` in
    ``[s_min_m, s_max_m]``; infinite limits give an infinite cylinder without caps.
    """
    a = np.asarray(axis_dir, dtype=float)
    m = np.broadcast_to(np.asarray(origin_m, dtype=float) - np.asarray(axis_point_m, dtype=float), dirs.shape)
    d_axial = dirs @ a
    m_axial = m @ a
    d_perp = dirs - d_axial[:, None] * a
    m_perp = m - m_axial[:, None] * a
    qa = np.einsum("ij,ij->i", d_perp, d_perp)
    qb = 2.0 * np.einsum("ij,ij->i", d_perp, m_perp)
    qc = np.einsum("ij,ij->i", m_perp, m_perp) - radius_m**2
    disc = qb * qb - 4.0 * qa * qc
    hits = (disc >= 0.0) & (qa > _EPS)
    safe_qa = np.where(hits, qa, 1.0)
    root = np.sqrt(np.where(hits, disc, 0.0))
    t_side = np.full(dirs.shape[0], np.inf)
    for sign in (-1.0, 1.0):  # near root first; the far root matters only inside a cap gap
        t = (-qb + sign * root) / (2.0 * safe_qa)
        s = m_axial + t * d_axial
        ok = hits & (t > 0.0) & (s >= s_min_m) & (s <= s_max_m)
        t_side = np.where(ok & (t < t_side), t, t_side)
    best = t_side
    for s_cap in (s_min_m, s_max_m):
        if not np.isfinite(s_cap):
            continue
        safe_axial = np.where(np.abs(d_axial) > _EPS, d_axial, 1.0)
        t = (s_cap - m_axial) / safe_axial
        radial = m_perp + t[:, None] * d_perp
        inside = np.einsum("ij,ij->i", radial, radial) <= radius_m**2
        ok = (np.abs(d_axial) > _EPS) & (t > 0.0) & inside
        best = np.where(ok & (t < best), t, best)
    return best


def ray_plane(
    origin_m: FloatArray, dirs: FloatArray, point_m: FloatArray, normal: FloatArray
) -> FloatArray:
    """Distance to an infinite plane through ``point_m`` with normal ``normal``."""
    n = np.asarray(normal, dtype=float)
    denom = dirs @ n
    num = (np.asarray(point_m, dtype=float) - np.asarray(origin_m, dtype=float)) @ n
    safe = np.where(np.abs(denom) > _EPS, denom, 1.0)
    t = num / safe
    return np.where((np.abs(denom) > _EPS) & (t > 0.0), t, np.inf)


def ray_rectangle(
    origin_m: FloatArray, dirs: FloatArray, corner_m: FloatArray, edge_u_m: FloatArray, edge_v_m: FloatArray
) -> FloatArray:
    """Distance to the rectangle ``corner + a*edge_u + b*edge_v`` with a, b in [0, 1]."""
    u = np.asarray(edge_u_m, dtype=float)
    v = np.asarray(edge_v_m, dtype=float)
    corner = np.asarray(corner_m, dtype=float)
    t = ray_plane(origin_m, dirs, corner, np.cross(u, v))
    finite = np.isfinite(t)
    rel = np.asarray(origin_m, dtype=float) + np.where(finite, t, 0.0)[:, None] * dirs - corner
    a = (rel @ u) / float(u @ u)
    b = (rel @ v) / float(v @ v)
    inside = finite & (a >= 0.0) & (a <= 1.0) & (b >= 0.0) & (b <= 1.0)
    return np.where(inside, t, np.inf)


def beams_near_sphere(angles_rad: FloatArray, centre_m: FloatArray, radius_m: float) -> FloatArray:
    """Indices of in-plane beams (rays from the origin in z = 0 at ``angles_rad``) that can
    pass within ``radius_m`` of ``centre_m``: a cheap cull before exact intersection."""
    cx, cy, cz = (float(v) for v in centre_m)
    if abs(cz) >= radius_m:
        return np.zeros(0, dtype=np.int64)
    radius_in_plane = float(np.sqrt(radius_m**2 - cz**2))
    distance = float(np.hypot(cx, cy))
    if distance <= radius_in_plane:
        return np.arange(angles_rad.size)
    half_width = float(np.arcsin(radius_in_plane / distance))
    offset = np.abs((angles_rad - np.arctan2(cy, cx) + np.pi) % (2.0 * np.pi) - np.pi)
    return np.flatnonzero(offset <= half_width + 1e-12)
