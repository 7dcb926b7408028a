"""Named trajectory presets, each a semicircle parameter set plus the rod it is made for.

The numbers are laid out for the fake cell's default scene, which also stands for a
typical real set-up: a UR5 base at the origin on a table (z = 0) and the scanner at
``T_base_laser`` translation (0.30, 0.50, 0.20) m, ZYX (5, 7, 3) deg, looking along
base +x; its scan plane is about 0.12-0.22 m above the table over the reachable area,
dropping towards +x. Every preset keeps, for every waypoint of that scene (tests check
this): the rod crossing the scan plane between its ends, the crossing 0.30-1.5 m from
the scanner and inside its 270 degree field of view (with 5 degrees to spare), the line
of sight clear of the robot base column, the TCP and both rod ends inside the default
workspace box (rod end above the table), and a UR5 solution. See docs/kinematics.md
for the reasoning behind the layout.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lasercal_hw.errors import ConfigError
from lasercal_hw.models import RodLine
from trajectories.semicircles import SemicircleParameters, semicircle_waypoints
from trajectories.waypoint import Waypoint

#: Height of the scan plane the presets are laid out for (base frame, metres).
SCAN_PLANE_HINT_Z_M = 0.2


@dataclass(frozen=True)
class Preset:
    """A named trajectory: its parameters, the rod it assumes, and what it is for."""

    name: str
    description: str
    parameters: SemicircleParameters
    rod: RodLine = field(default_factory=RodLine)

    def waypoints(self) -> list[Waypoint]:
        """The preset's waypoints in motion order."""
        return semicircle_waypoints(self.parameters, self.rod)


# Both arcs wrap around the side of a centre in front of the robot that faces the robot
# and the scanner (angles 82..262 deg). Centre, radii, heights, start, tilt and tool yaw
# minimise the Cramér-Rao bound of the solver's model (benchmarks/preset_design.py;
# docs/kinematics.md): crossings 0.32-1.25 m from the scanner at bearings -35..-115 deg,
# tilts of 30 deg, every waypoint on one elbow-up branch with room to spare.
_PAPER = SemicircleParameters(
    centre_m=(0.59, -0.19),
    radii_m=(0.35, 0.45),
    heights_m=(0.335, 0.275),
    start_deg=82.0,
    end_deg=262.0,
    step_deg=20.0,
    tilt_deg=30.0,
    tool_yaw_deg=104.0,
    scan_plane_z_m=SCAN_PLANE_HINT_Z_M,
)

# The scan plane slopes down towards +x (and up towards +y): rise per metre along base x
# and y, and its height at the drill arcs' centre.
_SCAN_PLANE_SLOPE = (-0.12, 0.04)
_DRILL_PLANE_HINT_Z_M = 0.14

PRESETS: dict[str, Preset] = {
    preset.name: preset
    for preset in (
        Preset(
            name="paper",
            description=(
                "The paper's procedure: two semicircles (r 0.35 and 0.45 m, TCP at 0.335 and 0.275 m), "
                "a 3 s stop every 20 deg (20 waypoints), tool tilted 30 deg in a new direction at each."
            ),
            parameters=_PAPER,
        ),
        Preset(
            name="compact",
            description=(
                "For a short reach or a cramped cell: smaller arcs (r 0.15 and 0.22 m) closer to the "
                "robot, 20 deg steps, 20 deg tilt."
            ),
            parameters=_PAPER.model_copy(
                update={
                    "centre_m": (0.55, -0.12),
                    "radii_m": (0.15, 0.22),
                    "heights_m": (0.35, 0.33),
                    "tilt_deg": 20.0,
                }
            ),
        ),
        Preset(
            name="drill",
            description=(
                "For a drill bit in the gripper: a 5 mm radius, 0.10 m bit starting 0.15 m from the "
                "flange; arcs (r 0.05 and 0.25 m) close to the scanner so the thin bit covers enough "
                "beams, parallel to the sloping scan plane so the crossing stays on the short bit, "
                "tilts up to 29 deg in seeded random directions."
            ),
            parameters=SemicircleParameters(
                centre_m=(0.61, 0.07),
                radii_m=(0.05, 0.25),
                heights_m=(0.34, 0.31),
                height_slope=_SCAN_PLANE_SLOPE,
                start_deg=42.0,
                end_deg=222.0,
                step_deg=20.0,
                tilt_deg=29.0,
                tool_yaw_deg=-102.0,
                seed=765,
                scan_plane_z_m=_DRILL_PLANE_HINT_Z_M,
            ),
            rod=RodLine(origin_m=np.array([0.0, 0.0, 0.15]), radius_m=0.005, length_m=0.10),
        ),
        Preset(
            name="quick",
            description=(
                "Few waypoints for CI and smoke tests: the paper's arcs with a stop every 40 deg "
                "(10 waypoints), still tilted in changing directions."
            ),
            parameters=_PAPER.model_copy(update={"step_deg": 40.0, "tool_yaw_deg": -40.0}),
        ),
    )
}

#: The preset used when none is named.
DEFAULT_PRESET = "paper"


def preset_names() -> list[str]:
    """Names of all presets, default first."""
    return [DEFAULT_PRESET, *sorted(n for n in PRESETS if n != DEFAULT_PRESET)]


def get_preset(name: str) -> Preset:
    """The preset called ``name`` (case-insensitive), or ConfigError listing the names."""
    preset = PRESETS.get(name.strip().lower())
    if preset is None:
        raise ConfigError(f"unknown trajectory preset {name!r}; choose one of: {', '.join(preset_names())}")
    return preset


def preset_waypoints(name: str = DEFAULT_PRESET) -> list[Waypoint]:
    """Waypoints of the named preset."""
    return get_preset(name).waypoints()
