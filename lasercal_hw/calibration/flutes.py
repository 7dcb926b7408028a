"""Where a twist drill's echo puts its centre, as a function of the drill's turn (docs/solver.md,
"Flute phase").

A beam's spot is wider than a drill bit, and a polished bit sends the beam back mostly from where
its surface faces the scanner square (a land's front, the flute's hollow, the wall where the
hollow meets the land), faintly from the rest. The pulse is far longer than the bit, so every part
the beam sees merges into one echo at their power-weighted range; a known-radius fit puts the
circle one radius behind it, in the middle of the bit's silhouette (the extraction centres a thin
rod's fit in its halo), so the centre lies off the axis by the echo's depth along the bearing.

The bit turns with the tool (it is in the chuck), and along its helix: at a crossing ``s``
metres down the bit, a flute's middle points along ``cos(b) x + sin(b) (axis x x)`` with ``b =
phase0 + 2 pi s / lead``, where ``x`` is the TCP's x axis made square to the bit's axis and
``phase0`` (the flute's turn from the TCP's x axis where the bit starts) is unknown: the solver
estimates it (``run/two_pass.py``). A bit tilted across the beam meets the scan plane at other
heights beside its axis, so the section the beam sees turns across the silhouette too. The
section (two flutes of ``opening`` each, a web of ``web_fraction`` of the diameter, circular-arc
flutes meeting the lands) is the usual twist drill's; the helix is right-handed (a standard
drill), ``lead = 2 pi r / tan(helix)``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from lasercal_hw.calibration.model import lines_in_scanner, plane_crossing
from lasercal_hw.geometry import FloatArray, pose_to_matrix
from lasercal_hw.models import RodLine

#: A standard (type N) twist drill's helix angle.
HELIX_DEG = 30.0
#: Each flute's opening of the section's circumference (as the extraction's settings).
FLUTE_OPENING_DEG = 100.0
#: The web over the diameter (as the extraction's settings).
WEB_FRACTION = 0.16


def _flute_arc(web_fraction: float, half_opening_rad: float) -> tuple[float, float]:
    """The flute's arc for a radius of 1: its centre's distance from the axis ``D`` and its
    radius ``rho``. The arc's deepest point is half the web from the axis (``D - rho = h``)
    and it meets the outer circle ``half_opening`` either side of the flute's middle:
    ``1 - 2 D cos(a) + D^2 = rho^2``, solved for D."""
    h, cos_a = web_fraction, np.cos(half_opening_rad)
    distance = (1.0 + h**2 - 2.0 * h * cos_a) / (2.0 * (cos_a - h)) + h
    return float(distance), float(distance - h)


#: Ground steel's specular lobe half-width (rad) and its diffuse part over its specular part:
#: the ``steel_drill`` material of docs/scanner-model.md (a microfacet lobe, Torrance and Sparrow
#: 1967; Li and Torrance 2005 for ground steel's spread).
LOBE_WIDTH_RAD = 0.06
DIFFUSE_OVER_SPECULAR = 0.01
#: The facings (deg from a flute's middle, 0-90) at which the echo is computed once, and the
#: lateral bins (over -1..1 radii across the silhouette) it is split into.
_TABLE_STEP_DEG = 0.25
_LATERAL_BINS = 80
#: Normals per radian along a curved surface, points along a flat wall, steps along a ray.
_NORMALS_PER_RAD = 600
_WALL_POINTS = 60
_RAY_STEPS = 96


def _near_branch_radius(polar_rad: FloatArray, distance: float, rho: float) -> FloatArray:
    """How far from the axis a ray leaving it at ``polar_rad`` (from a flute's middle) meets
    the flute's arc first (inf where it misses it): the section is star-shaped about the axis."""
    along = distance * np.cos(polar_rad)
    disc = along**2 - distance**2 + rho**2
    near = along - np.sqrt(np.fmax(disc, 0.0))
    return np.where((disc >= 0.0) & (along > 0.0), near, np.inf)


def _section_radius(polar_rad: FloatArray, distance: float, rho: float) -> FloatArray:
    """The section's edge at ``polar_rad`` (radii): the land's circle or either flute's arc."""
    return np.minimum(
        1.0,
        np.minimum(
            _near_branch_radius(polar_rad, distance, rho),
            _near_branch_radius(polar_rad - np.pi, distance, rho),
        ),
    )


def _surface(distance: float, rho: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The section's surface as points (P, 2), their outward normals' angles (P,) and the
    length each stands for (P,), radii, for the flute whose middle is the x axis and its
    lands (the other flute is the same turned half a turn): the flute's arc from its deepest
    point out to where a ray from the axis grazes it, the straight wall from there out to the
    land, and the land's circle."""
    graze = float(np.arccos(np.sqrt(1.0 - (rho / distance) ** 2)))  # polar angle of the wall
    graze_normal = np.pi / 2.0 - graze  # the arc's normal where it is grazed, and the wall's
    graze_radius = distance * np.cos(graze)
    n_arc = np.linspace(-graze_normal, graze_normal, int(2 * graze_normal * _NORMALS_PER_RAD) + 1)
    arc = np.array([distance, 0.0]) - rho * np.stack([np.cos(n_arc), np.sin(n_arc)], -1)
    n_land = np.linspace(graze, np.pi - graze, int((np.pi - 2 * graze) * _NORMALS_PER_RAD) + 1)
    land = np.stack([np.cos(n_land), np.sin(n_land)], -1)
    s = graze_radius + (1.0 - graze_radius) * (np.arange(_WALL_POINTS) + 0.5) / _WALL_POINTS
    wall = s[:, None] * np.array([np.cos(graze), np.sin(graze)])
    half = np.concatenate([arc, land, wall, wall * [1.0, -1.0]])
    normals = np.concatenate(
        [n_arc, n_land, np.full(_WALL_POINTS, -graze_normal), np.full(_WALL_POINTS, graze_normal)]
    )
    lengths = np.concatenate(
        [
            np.full(n_arc.size, rho * (n_arc[1] - n_arc[0])),
            np.full(n_land.size, n_land[1] - n_land[0]),
            np.full(2 * _WALL_POINTS, (1.0 - graze_radius) / _WALL_POINTS),
        ]
    )
    return (
        np.concatenate([half, -half]),
        np.concatenate([normals, normals + np.pi]),
        np.concatenate([lengths, lengths]),
    )


@lru_cache(maxsize=8)
def _echo_by_lateral(
    web_fraction: float, opening_deg: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """At facings 0-90 deg from a flute's middle (F,), split by lateral position across the
    silhouette (``_LATERAL_BINS`` over -1..1 radii, along the scanner's direction turned +90
    deg): the power the section sends back (F, L), that power times its depth towards the
    scanner (F, L) and whether the section covers the bin (F, L). Every part of the section the
    beam sees counts, weighted by its length, the cosine of its incidence and ground steel's
    specular lobe plus its diffuse part; parts the section hides from the scanner do not."""
    distance, rho = _flute_arc(web_fraction, np.radians(opening_deg) / 2.0)
    points, normals, lengths = _surface(distance, rho)
    facings = np.radians(np.arange(0.0, 90.0 + _TABLE_STEP_DEG / 2, _TABLE_STEP_DEG))
    steps = np.linspace(1e-3, 2.0, _RAY_STEPS)
    power = np.zeros((facings.size, _LATERAL_BINS))
    depth = np.zeros((facings.size, _LATERAL_BINS))
    cover = np.zeros((facings.size, _LATERAL_BINS), dtype=bool)
    for k, gamma in enumerate(facings):
        f = np.array([np.cos(gamma), np.sin(gamma)])
        across = np.array([-f[1], f[0]])
        incidence = np.angle(np.exp(1j * (normals - gamma)))
        lit = np.cos(incidence) > 0.0
        ray = points[lit, None, :] + steps[None, :, None] * f
        inside = (
            np.hypot(ray[..., 0], ray[..., 1])
            < _section_radius(np.arctan2(ray[..., 1], ray[..., 0]), distance, rho) - 1e-6
        )
        seen = np.flatnonzero(lit)[~inside.any(axis=1)]
        cos = np.cos(incidence[seen])
        lobe = np.exp(-((incidence[seen] / LOBE_WIDTH_RAD) ** 2)) + DIFFUSE_OVER_SPECULAR * cos
        part = lengths[seen] * cos * lobe
        bins = _lateral_bin(points[seen] @ across)
        np.add.at(power[k], bins, part)
        np.add.at(depth[k], bins, part * (points[seen] @ f))
        cover[k, _lateral_bin(points @ across)] = True
    return np.degrees(facings), power, depth, cover


def _lateral_bin(lateral: FloatArray) -> FloatArray:
    """The bin (of ``_LATERAL_BINS`` over -1..1 radii) of each lateral position."""
    return np.clip(((lateral + 1.0) / 2.0 * _LATERAL_BINS).astype(int), 0, _LATERAL_BINS - 1)


def glint_offsets(
    facing_rad: FloatArray,
    web_fraction: float = WEB_FRACTION,
    opening_deg: float = FLUTE_OPENING_DEG,
    *,
    turn_per_radius: FloatArray | float = 0.0,
) -> FloatArray:
    """The fitted centre's offset from the axis (N, 2), in radii, in the section frame whose
    x axis is a flute's middle, for the scanner's direction (seen from the bit) at
    ``facing_rad`` in that frame: one radius behind the echo (the power-weighted depth of every
    part of the section the scanner sees, ``_echo_by_lateral``) and, sideways, in the
    silhouette's middle. ``u`` radii aside from the axis (along the axis x the scanner's
    direction) the section is turned by ``turn_per_radius * u`` (rad; the helix where a tilted
    bit meets the plane there, ``flute_offsets_m``), so faces the scanner at ``facing -
    turn_per_radius * u``: each lateral bin's light is taken from its own turn."""
    facing = np.atleast_1d(np.asarray(facing_rad, dtype=float))
    turn = np.broadcast_to(np.asarray(turn_per_radius, dtype=float), facing.shape)
    table_deg, power, depth, cover = _echo_by_lateral(float(web_fraction), float(opening_deg))
    bins = np.arange(_LATERAL_BINS)
    u = (bins + 0.5) / _LATERAL_BINS * 2.0 - 1.0
    turned = facing[:, None] - turn[:, None] * u[None, :]
    folded = np.angle(np.exp(2j * turned)) / 2.0  # the section is point-symmetric
    mirrored = folded < 0.0  # and mirror-symmetric about a flute's middle, the sides swapped
    row = np.clip(np.rint(np.degrees(np.abs(folded)) / _TABLE_STEP_DEG).astype(int), 0, table_deg.size - 1)
    column = np.where(mirrored, _LATERAL_BINS - 1 - bins[None, :], bins[None, :])
    echo = depth[row, column].sum(axis=1) / power[row, column].sum(axis=1)
    lateral = np.where(cover[row, column], u[None, :], np.nan)
    middle = 0.5 * (np.nanmax(lateral, axis=1) + np.nanmin(lateral, axis=1))
    along = echo - 1.0
    cos, sin = np.cos(facing), np.sin(facing)
    return np.stack([along * cos - middle * sin, along * sin + middle * cos], -1)


def helix_lead_m(radius_m: float, helix_deg: float = HELIX_DEG) -> float:
    """The axial length of one turn of the flutes."""
    return 2.0 * np.pi * radius_m / np.tan(np.radians(helix_deg))


def _turns(
    phase0_rad: float, T_base_laser: FloatArray, tcp_poses: FloatArray, rod: RodLine, helix_deg: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """At each waypoint's crossing (scanner frame): the bit's axis, a flute's middle and the
    direction square to both (N, 3 each), and the scanner's direction seen from the bit in
    the (middle, across) frame (N,)."""
    T = np.asarray(T_base_laser, dtype=float)
    tcp = pose_to_matrix(np.atleast_2d(np.asarray(tcp_poses, dtype=float)))
    direction = np.asarray(rod.direction, dtype=float) / np.linalg.norm(rod.direction)
    origins = tcp[:, :3, :3] @ np.asarray(rod.origin_m, dtype=float) + tcp[:, :3, 3]
    directions = tcp[:, :3, :3] @ direction
    crossing, _, s = plane_crossing(T[:3, :3], T[:3, 3], origins, directions)
    _, axis = lines_in_scanner(T[:3, :3], T[:3, 3], origins, directions)
    tool_x = tcp[:, :3, 0] @ T[:3, :3]
    ref = tool_x - np.einsum("ij,ij->i", tool_x, axis)[:, None] * axis
    ref /= np.linalg.norm(ref, axis=1)[:, None]
    turn = phase0_rad + 2.0 * np.pi * s / helix_lead_m(rod.radius_m, helix_deg)
    middle = np.cos(turn)[:, None] * ref + np.sin(turn)[:, None] * np.cross(axis, ref)
    across = np.cross(axis, middle)
    to_scanner = -np.column_stack([crossing, np.zeros(len(crossing))])
    facing = np.arctan2(np.einsum("ij,ij->i", to_scanner, across), np.einsum("ij,ij->i", to_scanner, middle))
    return axis, middle, across, facing


def facing_angles_rad(
    phase0_rad: float,
    T_base_laser: FloatArray,
    tcp_poses: FloatArray,
    rod: RodLine,
    helix_deg: float = HELIX_DEG,
) -> FloatArray:
    """The scanner's direction seen from the bit, from a flute's middle, at each crossing (N,)."""
    return _turns(phase0_rad, T_base_laser, tcp_poses, rod, helix_deg)[3]


def flute_offsets_m(
    phase0_rad: float,
    T_base_laser: FloatArray,
    tcp_poses: FloatArray,
    rod: RodLine,
    *,
    web_fraction: float = WEB_FRACTION,
    opening_deg: float = FLUTE_OPENING_DEG,
    helix_deg: float = HELIX_DEG,
) -> FloatArray:
    """Where the centre found on a twist drill lies from its axis crossing (N, 2), in the scan
    plane, m: the section's offset (``glint_offsets``) at each waypoint's turn, carried along
    the bit's axis into the plane. A bit tilted across the beam meets the plane at other heights
    beside its axis: ``u`` radii aside (along ``w``, the axis x the scanner's direction) the
    plane lies ``-u r w_z / axis_z`` further down the bit, where the helix has turned the
    section by that times ``2 pi / lead``: ``-u tan(helix) w_z / axis_z``."""
    axis, middle, across, facing = _turns(phase0_rad, T_base_laser, tcp_poses, rod, helix_deg)
    aside = np.cos(facing)[:, None] * across - np.sin(facing)[:, None] * middle
    turn_per_radius = -aside[:, 2] / axis[:, 2] * np.tan(np.radians(helix_deg))
    g = glint_offsets(facing, web_fraction, opening_deg, turn_per_radius=turn_per_radius) * rod.radius_m
    offset = g[:, :1] * middle + g[:, 1:] * across
    in_plane = offset - (offset[:, 2] / axis[:, 2])[:, None] * axis
    return in_plane[:, :2]
