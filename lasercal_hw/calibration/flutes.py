"""Where a twist drill's echo puts its centre, as a function of the drill's turn (docs/solver.md,
"Flute phase").

A beam's spot is wider than a drill bit, and a polished bit sends the beam back from where its
surface faces the scanner square: a land's front (on the circle) or, when a flute faces the
scanner, the bottom of the flute's hollow, deeper and aside. A known-radius fit puts the circle
one radius behind that point, so the centre lies off the axis by ``glint + r * bearing``.

The bit turns with the tool (it is in the chuck), and along its helix: at a crossing ``s``
metres down the bit, a flute's middle points along ``cos(b) x + sin(b) (axis x x)`` with ``b =
phase0 + 2 pi s / lead``, where ``x`` is the TCP's x axis made square to the bit's axis and
``phase0`` (the flute's turn from the TCP's x axis where the bit starts) is unknown: the solver
estimates it (``run/two_pass.py``). The section (two flutes of ``opening`` each, a web of
``web_fraction`` of the diameter, circular-arc flutes meeting the lands) is the usual
twist drill's; the helix is right-handed (a standard drill), ``lead = 2 pi r / tan(helix)``.
"""

from __future__ import annotations

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


def glint_offsets(
    facing_rad: FloatArray,
    web_fraction: float = WEB_FRACTION,
    opening_deg: float = FLUTE_OPENING_DEG,
) -> FloatArray:
    """The fitted centre's offset from the axis (N, 2), in radii, in the section frame whose
    x axis is a flute's middle, for the scanner's direction (seen from the bit) at
    ``facing_rad`` in that frame. A land facing the scanner: 0. A flute facing it: its arc's
    point whose normal points at the scanner, if the lands do not hide it; else the land's
    edge next to it (the surface nearest to square)."""
    half = np.radians(opening_deg) / 2.0
    facing = np.asarray(facing_rad, dtype=float)
    flip = np.cos(facing) < 0.0  # the other flute: the section is point-symmetric
    gamma = np.where(flip, facing - np.pi, facing)
    gamma = np.angle(np.exp(1j * gamma))
    f = np.stack([np.cos(gamma), np.sin(gamma)], -1)
    distance, rho = _flute_arc(web_fraction, half)
    q = np.array([distance, 0.0]) - rho * f  # the arc's normal there points at the scanner
    qf = np.einsum("ij,ij->i", q, f)
    exit_t = -qf + np.sqrt(np.fmax(qf**2 - np.einsum("ij,ij->i", q, q) + 1.0, 0.0))
    exit_point = q + exit_t[:, None] * f
    seen = np.abs(np.arctan2(exit_point[:, 1], exit_point[:, 0])) <= half
    edge = np.stack([np.full_like(gamma, np.cos(half)), np.copysign(np.sin(half), gamma)], -1)
    offset = np.where(seen[:, None], q, edge) - f
    offset = np.where((np.abs(gamma) < half)[:, None], offset, 0.0)
    return np.where(flip[:, None], -offset, offset)


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
    the bit's axis into the plane."""
    axis, middle, across, facing = _turns(phase0_rad, T_base_laser, tcp_poses, rod, helix_deg)
    g = glint_offsets(facing, web_fraction, opening_deg) * rod.radius_m
    offset = g[:, :1] * middle + g[:, 1:] * across
    in_plane = offset - (offset[:, 2] / axis[:, 2])[:, None] * axis
    return in_plane[:, :2]
