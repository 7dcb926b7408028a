"""The paper's calibration trajectory, parameterised: semicircles of TCP positions.

Section 4.3 of the paper: the end effector moves along two semicircles with different
radii and heights, dwells every 20 degrees, and its orientation is varied at each stop.
Here each arc is a circle of ``radius`` around ``centre_m`` (base frame, x-y) at TCP
height ``height``; waypoints sit every ``step_deg`` from ``start_deg`` to ``end_deg``
(angles about base +z, measured from base +x). Every other arc runs backwards, so the
robot moves on from where the previous arc ended instead of flying back.

Orientation: the tool points down (TCP z axis along base -z, so a rod on the TCP z axis
hangs down through a roughly horizontal scan plane), its x axis along base x turned by
``tool_yaw_deg``, then tilted by ``tilt_deg`` about an axis in the tool's x-y plane.
Why tilts: with every rod vertical, the scanner's height and its roll/pitch barely move
the measured centres (they enter only through cosines); a rod tilted by t shifts its
crossing by ``dz * tan(t)`` when the plane moves by dz, which makes z, roll and pitch
observable. The default (deterministic) pattern turns the tilt direction by 135 degrees
from one waypoint to the next (nearly opposite neighbours; eight consecutive waypoints
cover all eight 45-degree directions) and offsets each arc by 67.5 degrees so the second
arc fills the directions in between. With ``seed`` set, directions are drawn uniformly
and magnitudes between half and all of ``tilt_deg`` (reproducible for a given seed).
"""

from __future__ import annotations

import logging
import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import FloatArray, make_transform, matrix_to_pose, rotvec_to_matrix
from lasercal_hw.models import RodLine
from trajectories.plane_crossing import horizontal_plane, rod_plane_crossings
from trajectories.waypoint import Waypoint, waypoint_matrices

logger = logging.getLogger(__name__)

# Consecutive tilt directions differ by this much; each further arc starts this much on.
TILT_DIRECTION_STEP_DEG = 135.0
ARC_TILT_OFFSET_DEG = 67.5
_ANGLE_EPS_DEG = 1e-9


class SemicircleParameters(BaseModel):
    """Parameters of the semicircle trajectory (base frame, metres and degrees)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    centre_m: tuple[float, float] = Field(description="arc centre (x, y) in the base frame")
    radii_m: tuple[float, ...] = Field(min_length=1, description="one radius per arc")
    heights_m: tuple[float, ...] = Field(min_length=1, description="TCP z of each arc (at the centre)")
    height_slope: tuple[float, float] = Field(
        (0.0, 0.0),
        description="rise of the TCP height per metre along base x and y "
        "(arcs parallel to a sloping scan plane)",
    )
    start_deg: float = Field(0.0, description="first angle of each arc about base +z from base +x")
    end_deg: float = Field(180.0, description="last angle of each arc")
    step_deg: float = Field(20.0, gt=0.0, le=180.0, description="angle between waypoints")
    tilt_deg: float = Field(20.0, ge=0.0, le=60.0, description="tool tilt away from straight down")
    tool_yaw_deg: float = Field(0.0, description="turn of the tool x axis about base z")
    seed: int | None = Field(None, description="None: fixed tilt pattern; int: seeded random tilts")
    scan_plane_z_m: float | None = Field(
        None,
        description="rough height of the scan plane above the centre (sloping by height_slope); "
        "if set, every rod must cross it",
    )

    @model_validator(mode="after")
    def _consistent(self) -> SemicircleParameters:
        if len(self.radii_m) != len(self.heights_m):
            raise ValueError(
                f"radii_m has {len(self.radii_m)} arcs but heights_m has {len(self.heights_m)}; "
                "give one height per radius"
            )
        if any(r <= 0.0 for r in self.radii_m):
            raise ValueError(f"radii_m must be positive, got {self.radii_m}")
        if abs(self.end_deg - self.start_deg) < self.step_deg - _ANGLE_EPS_DEG:
            raise ValueError(
                f"arc span {self.start_deg}..{self.end_deg} deg is shorter than step_deg {self.step_deg}"
            )
        return self

    def arc_angles_deg(self) -> list[float]:
        """Waypoint angles of one arc, from ``start_deg`` towards ``end_deg`` (inclusive)."""
        span = self.end_deg - self.start_deg
        count = math.floor(abs(span) / self.step_deg + _ANGLE_EPS_DEG) + 1
        direction = 1.0 if span >= 0 else -1.0
        return [self.start_deg + direction * self.step_deg * k for k in range(count)]


def parse_semicircle_parameters(data: object, source: str = "trajectory") -> SemicircleParameters:
    """Validate user input (a mapping, e.g. from TOML) into parameters, or raise ConfigError
    naming each bad field."""
    try:
        return SemicircleParameters.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in err['loc']) or 'parameters'}: {err['msg']}" for err in exc.errors()
        )
        raise ConfigError(f"{source}: invalid semicircle parameters: {problems}") from None


def _tilts_deg(
    params: SemicircleParameters, arc: int, count: int, first_index: int, rng: np.random.Generator | None
) -> list[tuple[float, float]]:
    """(magnitude, direction) of the tool tilt for each waypoint of one arc."""
    if rng is None:
        return [
            (
                params.tilt_deg,
                (TILT_DIRECTION_STEP_DEG * (first_index + k) + ARC_TILT_OFFSET_DEG * arc) % 360.0,
            )
            for k in range(count)
        ]
    return [
        (params.tilt_deg * float(rng.uniform(0.5, 1.0)), float(rng.uniform(0.0, 360.0))) for _ in range(count)
    ]


def tool_orientation(tool_yaw_deg: float, tilt_deg: float, tilt_direction_deg: float) -> np.ndarray:
    """Rotation base-to-TCP: tool pointing down, x axis turned by the yaw, then tilted.

    The tilt turns the tool by ``tilt_deg`` about the tool-frame axis
    ``(cos(dir), sin(dir), 0)``; a tilt about tool x (dir 0) swings the rod end along -y
    of the tool.
    """
    down = rotvec_to_matrix([0.0, 0.0, math.radians(tool_yaw_deg)]) @ rotvec_to_matrix([math.pi, 0.0, 0.0])
    direction = math.radians(tilt_direction_deg)
    tilt = math.radians(tilt_deg) * np.array([math.cos(direction), math.sin(direction), 0.0])
    return down @ rotvec_to_matrix(tilt)


def semicircle_waypoints(params: SemicircleParameters, rod: RodLine | None = None) -> list[Waypoint]:
    """Waypoints of all arcs in motion order, indexed from 0.

    With ``params.scan_plane_z_m`` set, raises ConfigError (listing each waypoint) when a
    rod (``rod``, default ``RodLine()``) would not cross that horizontal plane.
    """
    rng = None if params.seed is None else np.random.default_rng(params.seed)
    angles = params.arc_angles_deg()
    waypoints: list[Waypoint] = []
    for arc, (radius, height) in enumerate(zip(params.radii_m, params.heights_m, strict=True)):
        arc_angles = angles if arc % 2 == 0 else angles[::-1]
        tilts = _tilts_deg(params, arc, len(arc_angles), len(waypoints), rng)
        for angle_deg, (tilt_deg, tilt_dir_deg) in zip(arc_angles, tilts, strict=True):
            theta = math.radians(angle_deg)
            offset = (radius * math.cos(theta), radius * math.sin(theta))
            position = [
                params.centre_m[0] + offset[0],
                params.centre_m[1] + offset[1],
                height + params.height_slope[0] * offset[0] + params.height_slope[1] * offset[1],
            ]
            rotation = tool_orientation(params.tool_yaw_deg, tilt_deg, tilt_dir_deg)
            pose = matrix_to_pose(make_transform(rotation, position))
            label = (
                f"arc {arc + 1} at {angle_deg:+.0f} deg, "
                f"tilt {tilt_deg:.1f} deg toward {tilt_dir_deg:.1f} deg"
            )
            waypoints.append(
                Waypoint(index=len(waypoints), tcp_pose=tuple(float(v) for v in pose), label=label)
            )
    if params.scan_plane_z_m is not None:
        _require_plane_crossings(waypoints, rod or RodLine(), params)
    logger.debug("generated %d semicircle waypoints", len(waypoints))
    return waypoints


def hint_plane(params: SemicircleParameters) -> FloatArray:
    """``T_base_plane`` of the scan plane the parameters assume: through the centre at height
    ``scan_plane_z_m``, sloping like the arcs (``height_slope``)."""
    if params.scan_plane_z_m is None:
        raise ConfigError("the parameters give no scan_plane_z_m")
    plane = horizontal_plane(params.scan_plane_z_m)
    normal = np.array([-params.height_slope[0], -params.height_slope[1], 1.0])
    normal /= np.linalg.norm(normal)
    axis = np.cross([0.0, 0.0, 1.0], normal)
    tilt_rad = math.atan2(float(np.linalg.norm(axis)), float(normal[2]))
    rotvec = axis / np.linalg.norm(axis) * tilt_rad if tilt_rad > 0.0 else np.zeros(3)
    plane[:3, :3] = rotvec_to_matrix(rotvec)
    plane[:2, 3] = params.centre_m
    return plane


def _require_plane_crossings(waypoints: list[Waypoint], rod: RodLine, params: SemicircleParameters) -> None:
    plane_z_m = params.scan_plane_z_m
    crossings = rod_plane_crossings(waypoint_matrices(waypoints), rod, hint_plane(params))
    missing = [
        f"{w.index} ({'no crossing' if not np.isfinite(s) else f'crosses {s:.3f} m along the rod'})"
        for w, s, ok in zip(waypoints, crossings.along_rod_m, crossings.within_rod, strict=True)
        if not ok
    ]
    if missing:
        raise ConfigError(
            f"the rod ({rod.length_m:.3f} m) does not cross the scan plane hint z = {plane_z_m:.3f} m at "
            f"waypoint(s) {', '.join(missing)}; put heights_m between the plane and the plane plus the "
            "rod length, or use a longer rod"
        )
