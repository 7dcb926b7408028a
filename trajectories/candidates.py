"""Candidate waypoints for a design: TCP poses whose rod crosses a scanner's plane and that
keep every rule a run applies, even where the scanner is off its rough pose by the stated
uncertainty.

A candidate is drawn as a crossing point in the scan plane (range and bearing from the
scanner), a rod direction tilted from the plane normal, where along the rod the crossing
falls, and a turn of the tool about the rod (small, or wide when the rod's axis is
estimated). A polished rod (``rod.polished``: a steel drill bit) is tilted across the beam,
leaning along it by at most ``POLISHED_MAX_BEAM_LEAN_DEG``: its surface sends the beam back
only where it faces the scanner square, so a rod leaning toward or away from the scanner
returns little more than its faint diffuse part (docs/scanner-model.md). Each is then kept
only if:

- the crossing lies 0.30 m (clear of the scanner) to ``max_range_m`` from the scanner, where
  the rod still covers enough beams, and inside the field of view with a margin;
- the rod crosses between its ends with ``END_MARGIN_M`` to spare at both ends even if the
  plane is off by the pose uncertainty (translation ``t`` and rotation ``r`` move the plane
  at range ``rho`` by up to ``t + r * rho`` along its normal, so along a rod tilted by
  ``tau`` by that over ``cos(tau)``);
- the beam from the scanner to the crossing, and on ``BACKDROP_M`` beyond it, passes the
  robot's base axis with ``COLUMN_CLEARANCE_M`` (plus the translation uncertainty) to spare:
  a surface close behind the rod blends into its edge beams and moves its centre sideways
  (a polished rod's faint echo merges with it whole);
- the TCP and both rod ends lie inside the workspace box;
- the arm reaches the pose on the design's inverse-kinematics branch with the elbow and
  the wrist away from their singularities.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from lasercal_hw.geometry import FloatArray, make_transform
from lasercal_hw.models import RodLine
from lasercal_hw.ur_kinematics import UR5, URModel, forward_kinematics, inverse_kinematics_branches

#: Least distance of the crossing from either rod end (m).
END_MARGIN_M = 0.025
#: Least crossing range: clear of the scanner's body (m).
MIN_RANGE_M = 0.30
#: Largest crossing range for a thick rod (m).
MAX_RANGE_M = 1.5
#: Beams that must fall across the rod's diameter at the crossing (fixes the range limit
#: of a thin rod: 4 beams of 0.25 deg over 10 mm at 0.57 m).
MIN_BEAMS_ACROSS = 4.0
#: Angle between beams of the UTM-30LX-EW (rad).
BEAM_STEP_RAD = np.deg2rad(0.25)
#: Half field of view of the UTM-30LX-EW (deg) and the margin kept inside it.
HALF_FIELD_OF_VIEW_DEG = 135.0
FIELD_OF_VIEW_MARGIN_DEG = 5.0
#: Least distance of a beam from the robot's base axis (m): column radius plus a margin.
COLUMN_CLEARANCE_M = 0.13
#: Tilt of the rod from the plane normal (deg). The plane's height and its tilt (the weak
#: rotations about the plane's own axes) move a crossing only by tan(tilt) times their shift,
#: so the information on them grows with tan^2(tilt) until the robot's error along the rod
#: (also scaled by tan(tilt)) dominates: 40 deg gives nearly twice 30 deg's. The ellipse a steep
#: rod cuts is fitted as one in the run's second pass (docs/extraction.md).
TILT_RANGE_DEG = (10.0, 40.0)
#: Largest lean of a polished rod along the beam (deg), the pose uncertainty's rotation
#: included: ground steel's specular lobe is about 3.4 deg wide (docs/scanner-model.md).
POLISHED_MAX_BEAM_LEAN_DEG = 3.0
#: A surface this close behind the rod (m) blends into its edge beams (the pulse is about a
#: metre long; a polished rod's faint echo merges whole): the beam must pass the robot's base
#: by the line-of-sight clearance this far beyond the crossing too.
BACKDROP_M = 0.5
#: Turn of the tool about the rod around its reference heading (deg): keeps joint 6 calm.
TOOL_TURN_SPREAD_DEG = 30.0
#: The same when the rod's axis is estimated: turning the tool about the rod moves an axis
#: offset around in the base frame, which tells it apart from the scanner's position.
AXIS_TOOL_TURN_SPREAD_DEG = 150.0
#: Elbow (|theta3|) and wrist (|theta5|) kept this far from stretched, folded or flipped (rad).
ELBOW_RANGE_RAD = (0.45, np.pi - 0.8)
WRIST_MARGIN_RAD = 0.5
#: Least distance (largest joint, rad) from a pose's solution to that of another branch.
BRANCH_GAP_RAD = 1.0
#: Posture the designs start from: UR's home (the branch every waypoint must be on).
HOME_Q_RAD = np.array([0.0, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])
#: Slack on the linearised plane shift (second-order terms at 5 cm / 5 deg).
_UNCERTAINTY_SLACK = 1.05


@dataclass(frozen=True)
class PoseUncertainty:
    """How far the true scanner pose may be from the rough one: any translation up to
    ``translation_m`` combined with any rotation up to ``rotation_deg``."""

    translation_m: float = 0.05
    rotation_deg: float = 5.0

    @property
    def rotation_rad(self) -> float:
        """The rotation bound in radians."""
        return float(np.deg2rad(self.rotation_deg))


#: The default: 5 cm and 5 degrees, a careful tape measure.
DEFAULT_UNCERTAINTY = PoseUncertainty()


@dataclass(frozen=True)
class CellRules:
    """What the candidates must respect besides the scanner: arm, box and rod."""

    rod: RodLine
    box_min_m: tuple[float, float, float]
    box_max_m: tuple[float, float, float]
    model: URModel = UR5
    branch: int = 2
    #: The rod's surface is polished: tilt it across the beam only.
    polished: bool = False

    def max_range_m(self) -> float:
        """The farthest crossing at which the rod still covers ``MIN_BEAMS_ACROSS`` beams."""
        return float(min(MAX_RANGE_M, 2.0 * self.rod.radius_m / (MIN_BEAMS_ACROSS * BEAM_STEP_RAD)))


@dataclass
class CandidatePool:
    """Kept candidates and, for the report, how many each rule removed."""

    T_base_tcp: FloatArray
    joints_rad: FloatArray
    crossing_base_m: FloatArray
    crossing_range_m: FloatArray
    crossing_bearing_rad: FloatArray
    #: +1 where the TCP is on the side the plane normal points to, -1 on the other side.
    side: FloatArray
    drawn: int = 0
    removed: dict[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.T_base_tcp)


def home_branch(model: URModel) -> int:
    """The IK branch of UR's home posture on ``model`` (see ``ur_kinematics``)."""
    home = forward_kinematics(HOME_Q_RAD, model=model)
    branches = inverse_kinematics_branches(home[None], model=model)[0]
    error = np.abs((branches - HOME_Q_RAD + np.pi) % (2 * np.pi) - np.pi).max(axis=1)
    return int(np.nanargmin(error))


def crossing_window_m(
    rod: RodLine, range_m: FloatArray, cos_tilt: FloatArray, uncertainty: PoseUncertainty
) -> tuple[FloatArray, FloatArray]:
    """Lowest and highest crossing distance along the rod that keeps ``END_MARGIN_M`` from
    both ends wherever inside ``uncertainty`` the plane really is (low > high: none)."""
    shift_m = _UNCERTAINTY_SLACK * (uncertainty.translation_m + uncertainty.rotation_rad * range_m) / cos_tilt
    return END_MARGIN_M + shift_m, rod.length_m - END_MARGIN_M - shift_m


def robust_max_range_m(
    rod: RodLine, uncertainty: PoseUncertainty, rules: CellRules, tilt_rad: FloatArray
) -> FloatArray:
    """The farthest range at which a rod tilted by ``tilt_rad`` still has a crossing window
    (drawing beyond it is wasted), capped by the beam count; per tilt. The window's half
    length shrinks with ``cos(tilt)`` while the plane's shift grows with ``t + r * range``."""
    half_window_m = (rod.length_m - 2.0 * END_MARGIN_M) / 2.0 * np.cos(tilt_rad)
    spare_m = half_window_m / _UNCERTAINTY_SLACK - uncertainty.translation_m
    if uncertainty.rotation_rad > 0.0:
        return np.minimum(rules.max_range_m(), spare_m / uncertainty.rotation_rad)
    return np.where(spare_m >= 0.0, rules.max_range_m(), MIN_RANGE_M)


def _orientations(
    direction: FloatArray, heading: FloatArray, turn_rad: FloatArray, rod: RodLine
) -> FloatArray:
    """Rotations base-to-TCP (n, 3, 3) putting the rod axis along ``direction`` and the
    tool's reference axis along ``heading`` turned by ``turn_rad`` about the rod."""
    u = rod.unit_direction()
    x_tool = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x_tool = x_tool - (x_tool @ u) * u
    x_tool /= np.linalg.norm(x_tool)
    tool_frame = np.stack([x_tool, np.cross(u, x_tool), u], axis=1)
    h = heading - np.sum(heading * direction, axis=1, keepdims=True) * direction
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    side = np.cross(direction, h)
    x_base = np.cos(turn_rad)[:, None] * h + np.sin(turn_rad)[:, None] * side
    base_frame = np.stack([x_base, np.cross(direction, x_base), direction], axis=2)
    return base_frame @ tool_frame.T


def _gap_to_other_branches(solutions: FloatArray, branch: int) -> FloatArray:
    """Largest-joint distance (rad) from each pose's solution on ``branch`` to its nearest
    solution on another branch (inf when there is none)."""
    own = solutions[:, branch : branch + 1]
    others = np.delete(solutions, branch, axis=1)
    with np.errstate(invalid="ignore"):
        distance = np.abs((others - own + np.pi) % (2 * np.pi) - np.pi).max(axis=2)
    return np.nan_to_num(distance, nan=np.inf).min(axis=1)


def _across_the_beam(
    bearing_rad: FloatArray, tilt_rad: FloatArray, drawn_rad: FloatArray, uncertainty: PoseUncertainty
) -> FloatArray:
    """Tilt directions (in the scan plane) that lean a rod tilted by ``tilt_rad`` along the
    beam at ``bearing_rad`` by at most ``POLISHED_MAX_BEAM_LEAN_DEG`` less the rotation
    uncertainty, to either side of the beam (the drawn directions pick the side and the
    spread): the lean along the beam is ``asin(sin tilt cos(direction - bearing))``."""
    lean_rad = np.deg2rad(max(POLISHED_MAX_BEAM_LEAN_DEG - uncertainty.rotation_deg, 0.0))
    spread = np.arcsin(np.clip(np.sin(lean_rad) / np.sin(tilt_rad), 0.0, 1.0))
    side = np.where(np.sin(drawn_rad) >= 0.0, 1.0, -1.0)
    offset = spread * np.cos(drawn_rad)  # within the allowed spread, as drawn
    return bearing_rad + side * (0.5 * np.pi - offset)


def column_distance_m(scanner_xy: FloatArray, points_xy: FloatArray) -> FloatArray:
    """Distance of the base axis (x = y = 0) from each beam segment, in the base xy plane."""
    beam = points_xy - scanner_xy
    along = np.clip((-scanner_xy @ beam.T) / np.maximum(np.sum(beam * beam, axis=1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(scanner_xy + along[:, None] * beam, axis=1)


def draw_candidates(
    T_base_laser: FloatArray,
    uncertainty: PoseUncertainty,
    rules: CellRules,
    count: int,
    rng: np.random.Generator,
    on_progress: Callable[[float], None] | None = None,
    turn_spread_deg: float = TOOL_TURN_SPREAD_DEG,
) -> CandidatePool:
    """Draw ``count`` candidates around the rough scanner pose and keep those that pass; the
    tool turns up to ``turn_spread_deg`` either way about the rod."""
    rod = rules.rod
    removed: dict[str, int] = {}

    def keep(mask: np.ndarray, rule: str) -> None:
        removed[rule] = removed.get(rule, 0) + int((~mask).sum())

    rotation, scanner = T_base_laser[:3, :3], T_base_laser[:3, 3]
    e1, e2, normal = rotation[:, 0], rotation[:, 1], rotation[:, 2]
    tilt_rad = np.deg2rad(rng.uniform(*TILT_RANGE_DEG, count))
    farthest_m = np.maximum(MIN_RANGE_M, robust_max_range_m(rod, uncertainty, rules, tilt_rad))
    range_m = rng.uniform(MIN_RANGE_M, farthest_m)
    bearing_rad = np.deg2rad(rng.uniform(-HALF_FIELD_OF_VIEW_DEG, HALF_FIELD_OF_VIEW_DEG, count))
    tilt_direction_rad = rng.uniform(0.0, 2.0 * np.pi, count)
    if rules.polished:
        tilt_direction_rad = _across_the_beam(bearing_rad, tilt_rad, tilt_direction_rad, uncertainty)
    side = rng.choice([-1.0, 1.0], count)
    turn_rad = np.deg2rad(rng.uniform(-turn_spread_deg, turn_spread_deg, count))
    along_fraction = rng.uniform(0.0, 1.0, count)

    margin_deg = (
        FIELD_OF_VIEW_MARGIN_DEG + uncertainty.rotation_deg + np.degrees(uncertainty.translation_m / range_m)
    )
    ok = np.abs(np.degrees(bearing_rad)) <= HALF_FIELD_OF_VIEW_DEG - margin_deg
    keep(ok, "outside the field of view (with margin)")
    crossing = scanner + range_m[:, None] * (
        np.cos(bearing_rad)[:, None] * e1 + np.sin(bearing_rad)[:, None] * e2
    )
    clearance_m = COLUMN_CLEARANCE_M + uncertainty.translation_m
    clear = column_distance_m(scanner[:2], crossing[:, :2]) >= clearance_m
    keep(clear | ~ok, "beam passes the robot's base")
    ok &= clear
    beyond = crossing + BACKDROP_M * (crossing - scanner) / range_m[:, None]
    backdrop = column_distance_m(scanner[:2], beyond[:, :2]) >= clearance_m
    keep(backdrop | ~ok, "the rod right before the robot's base")
    ok &= backdrop
    low, high = crossing_window_m(rod, range_m, np.cos(tilt_rad), uncertainty)
    window = low <= high
    keep(window | ~ok, "rod too short for the pose uncertainty at that range")
    ok &= window
    direction = -side[:, None] * np.cos(tilt_rad)[:, None] * normal + np.sin(tilt_rad)[:, None] * (
        np.cos(tilt_direction_rad)[:, None] * e1 + np.sin(tilt_direction_rad)[:, None] * e2
    )
    along_m = low + along_fraction * (high - low)
    tcp_rotation = _orientations(direction, np.broadcast_to(e1, direction.shape), turn_rad, rod)
    origin = crossing - along_m[:, None] * direction
    tcp = origin - tcp_rotation @ np.asarray(rod.origin_m, dtype=float)
    tip = origin + rod.length_m * direction
    low_box, high_box = np.asarray(rules.box_min_m), np.asarray(rules.box_max_m)
    inside = np.ones(count, dtype=bool)
    for point in (tcp, origin, tip):
        inside &= np.all((point >= low_box) & (point <= high_box), axis=1)
    keep(inside | ~ok, "TCP or rod end outside the workspace box")
    ok &= inside

    index = np.flatnonzero(ok)
    transforms = make_transform(tcp_rotation[index], tcp[index])
    joints = np.full((len(index), 6), np.nan)
    chunks = np.array_split(np.arange(len(index)), max(1, min(10, len(index) // 200)))
    branch_gap = np.zeros(len(index))
    for done, chunk in enumerate(chunks, start=1):
        solutions = inverse_kinematics_branches(transforms[chunk], model=rules.model)
        joints[chunk] = solutions[:, rules.branch]
        branch_gap[chunk] = _gap_to_other_branches(solutions, rules.branch)
        if on_progress is not None:
            on_progress(done / len(chunks))
    reachable = np.all(np.isfinite(joints), axis=1)
    keep(reachable, f"not reachable on IK branch {rules.branch}")
    apart = branch_gap >= BRANCH_GAP_RAD
    keep(apart | ~reachable, "another IK branch too close (the controller might switch to it)")
    reachable &= apart
    with np.errstate(invalid="ignore"):
        elbow = np.abs(joints[:, 2])
        wrist = np.abs(joints[:, 4])
        posture = (
            (elbow >= ELBOW_RANGE_RAD[0]) & (elbow <= ELBOW_RANGE_RAD[1])
            & (wrist >= WRIST_MARGIN_RAD) & (wrist <= np.pi - WRIST_MARGIN_RAD)
        )
    keep(posture | ~reachable, "elbow or wrist near a singularity")
    final = reachable & posture
    return CandidatePool(
        T_base_tcp=transforms[final],
        joints_rad=joints[final],
        crossing_base_m=crossing[index][final],
        crossing_range_m=range_m[index][final],
        crossing_bearing_rad=bearing_rad[index][final],
        side=side[index][final],
        drawn=count,
        removed=removed,
    )

