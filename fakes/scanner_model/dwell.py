"""A dwell's raw scans of one rod in front of a wall, for extraction tests and benchmarks.

    from fakes.scanner_model.dwell import simulate_dwell
    dwell = simulate_dwell((0.8, 0.1), 0.02, material="retro_tape", background_m=0.5, seed=1)
    dwell.scans            # list[LaserScan], what the driver would deliver (ME: with intensities)
    dwell.background       # the same view without the rod
    dwell.centre_uv_m      # the truth: where the rod's axis pierces the scan plane
    dwell.world.scan_ranges_m(dwell.T_base_tcp)   # the same view without random parts

The scanner is level, the rod crosses the scan plane at ``centre_uv_m`` (scanner frame)
along ``axis``; an optional wall faces the scanner ``background_m`` behind the rod, and
further walls (``walls``: a background not square to the bearing) stand where they are put.
Everything else (beam layout, physics) is a scene (``fakes/scene.py``) built here, so the
scans come from the same world the fake cell serves.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fakes.scene import Material, ModelName, PhysicsSettings, Scene
from fakes.world import World
from lasercal_hw.geometry import make_transform
from lasercal_hw.models import FloatArray, LaserScan

_SCANNER_HEIGHT_M = 1.0
_ROD_LENGTH_M = 0.3
_WALL_HALF_WIDTH_M = 3.0
_AWAY_M = 5.0
_PLACED_WALL_HALF_WIDTH_M = 2.0

Segment = tuple[tuple[float, float], tuple[float, float]]


@dataclass(frozen=True)
class SimulatedDwell:
    """Raw scans with the rod, raw scans without it, and the truth."""

    scans: list[LaserScan]
    background: list[LaserScan]
    centre_uv_m: FloatArray
    radius_m: float
    world: World
    T_base_tcp: FloatArray

    def returned_power_bearing_rad(self) -> float:
        """Where a noise-free scan says a lone rod is, no extraction involved: the bearing of
        the beams that return it, weighted by their power (the square of the intensity)."""
        raw_mm, intensity = self.world.scan_mm(self.T_base_tcp, None)
        seen = raw_mm >= round(self.world.geometry.min_range_m * 1000.0)
        power = intensity[seen].astype(float) ** 2
        return float(np.sum(power * self.world.angles_rad[seen]) / power.sum())


def simulate_dwell(
    centre_uv_m: Sequence[float],
    radius_m: float,
    *,
    material: Material = "painted",
    shape: str = "cylinder",
    axis: Sequence[float] = (0.0, 0.0, 1.0),
    spindle_deg: float = 0.0,
    background_m: float | None = 0.5,
    wall_material: Material = "matte",
    walls: Sequence[Segment] = (),
    posts: Sequence[tuple[float, float, float]] = (),
    post_material: Material = "painted",
    scan_count: int = 40,
    background_count: int = 0,
    seed: int = 0,
    model: ModelName = "physical",
    physics: PhysicsSettings | None = None,
    elapsed_s: float | None = None,
) -> SimulatedDwell:
    """``scan_count`` scans (40 per second) of a rod of ``radius_m`` crossing the scan plane
    at ``centre_uv_m``; ``shape`` is ``cylinder`` or ``twist_drill`` (turned by
    ``spindle_deg`` about its axis); ``background_m``: distance from the rod's centre to a
    wall behind it (None: open space); ``walls``: further walls ``((u, v), (u, v))`` from
    end to end in the scanner frame, of ``wall_material``; ``posts``: other vertical
    cylinders ``(u, v, radius)`` in the scanner frame, of ``post_material`` (clutter the size
    of a rod); ``elapsed_s``: time since power-on at the first scan (None: warm).  Seeded by
    ``seed``: the same arguments give the same scans."""
    centre = np.array([float(centre_uv_m[0]), float(centre_uv_m[1]), 0.0])
    post_list = [
        {"name": f"post {k}", "centre_m": [u, v], "radius_m": r, "material": post_material}
        for k, (u, v, r) in enumerate(posts)
    ]
    wall_list = [
        {"name": f"wall {k}", "start_m": list(start), "end_m": list(end)}
        for k, (start, end) in enumerate(walls)
    ]
    world = World(_scene(
        centre, radius_m, material, shape, background_m, wall_material, wall_list, post_list, model, physics
    ))
    z = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    x = np.cross([0.0, 1.0, 0.0], z) if abs(z[1]) < 0.9 else np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    turn = np.radians(spindle_deg)
    x = np.cos(turn) * x + np.sin(turn) * np.cross(z, x)
    R = np.column_stack([x, np.cross(z, x), z])
    T_laser = world.ground_truth_T_base_laser
    at_rod = T_laser @ make_transform(R, centre - 0.5 * _ROD_LENGTH_M * z)
    away = T_laser @ make_transform(R, centre + _AWAY_M * np.array([0.0, 0.0, 1.0]))
    return SimulatedDwell(
        scans=_scans(world, at_rod, scan_count, seed, elapsed_s),
        background=_scans(world, away, background_count, seed + 1_000_003, elapsed_s),
        centre_uv_m=centre[:2],
        radius_m=radius_m,
        world=world,
        T_base_tcp=at_rod,
    )


def oblique_wall(centre_uv_m: Sequence[float], behind_m: float, turn_deg: float) -> list[Segment]:
    """A wall ``behind_m`` behind a rod at ``centre_uv_m`` (along its bearing), seen ``turn_deg``
    from its normal (positive: its far end on the side counterclockwise of the bearing)."""
    along, across = _bearing_frame(centre_uv_m)
    middle = (float(np.linalg.norm(centre_uv_m)) + behind_m) * along
    turn = np.radians(turn_deg)
    direction = np.cos(turn) * across + np.sin(turn) * along
    reach = _PLACED_WALL_HALF_WIDTH_M * direction
    return [_segment(middle - reach, middle + reach)]


def step_behind_edge(
    centre_uv_m: Sequence[float], radius_m: float, side: int, near_behind_m: float, far_behind_m: float
) -> list[Segment]:
    """A step in the background behind one edge of a rod at ``centre_uv_m``: a wall
    ``near_behind_m`` behind it whose end lies on the ray past the rod's edge on ``side`` (+1:
    counterclockwise of the bearing, -1: clockwise) and runs away from the rod, and a wall
    ``far_behind_m`` behind across the whole view."""
    along, across = _bearing_frame(centre_uv_m)
    range_m = float(np.linalg.norm(centre_uv_m))
    edge = np.arctan2(along[1], along[0]) + side * np.arcsin(radius_m / range_m)
    ray = np.array([np.cos(edge), np.sin(edge)])
    corner = (range_m + near_behind_m) / float(ray @ along) * ray
    far = (range_m + far_behind_m) * along
    reach = _PLACED_WALL_HALF_WIDTH_M * across
    return [_segment(corner, corner + side * reach), _segment(far - reach, far + reach)]


def _bearing_frame(centre_uv_m: Sequence[float]) -> tuple[FloatArray, FloatArray]:
    """Unit vectors along a rod's bearing and across it (counterclockwise)."""
    along = np.asarray(centre_uv_m, dtype=float)[:2] / float(np.linalg.norm(np.asarray(centre_uv_m)[:2]))
    return along, np.array([-along[1], along[0]])


def _segment(start: FloatArray, end: FloatArray) -> Segment:
    return (float(start[0]), float(start[1])), (float(end[0]), float(end[1]))


def _scene(
    centre: FloatArray,
    radius_m: float,
    material: str,
    shape: str,
    background_m: float | None,
    wall_material: str,
    placed_walls: list[dict[str, object]],
    posts: list[dict[str, object]],
    model: str,
    physics: PhysicsSettings | None,
) -> Scene:
    walls = [
        {**wall, "z_min_m": 0.0, "z_max_m": 2.0 * _SCANNER_HEIGHT_M, "material": wall_material}
        for wall in placed_walls
    ]
    if background_m is not None:
        distance = float(np.linalg.norm(centre[:2])) + background_m
        direction = centre[:2] / np.linalg.norm(centre[:2])
        across = np.array([-direction[1], direction[0]])
        middle = distance * direction
        walls.append({
            "name": "behind",
            "start_m": list(middle - _WALL_HALF_WIDTH_M * across),
            "end_m": list(middle + _WALL_HALF_WIDTH_M * across),
            "z_min_m": 0.0,
            "z_max_m": 2.0 * _SCANNER_HEIGHT_M,
            "material": wall_material,
        })
    data = {
        "model": model,
        "scanner": {"translation_m": [0.0, 0.0, _SCANNER_HEIGHT_M], "euler_zyx_deg": [0.0, 0.0, 0.0]},
        "rod": {"radius_m": radius_m, "length_m": _ROD_LENGTH_M, "material": material, "shape": shape},
        "column": {"enabled": False},
        "floor": {"enabled": False},
        "walls": walls,
        "posts": posts,
        "noise": {"robot_position_error_m": 0.0, "robot_rotation_error_deg": 0.0},
    }
    scene = Scene.model_validate(data)
    if physics is not None:
        scene = scene.model_copy(update={"physics": physics})
    return scene


def _scans(
    world: World, T_base_tcp: FloatArray, count: int, seed: int, elapsed_s: float | None
) -> list[LaserScan]:
    period_s = world.geometry.scan_period_s
    out = []
    for k in range(count):
        rng = np.random.default_rng([seed, k])
        elapsed = None if elapsed_s is None else elapsed_s + k * period_s
        raw_mm, intensities = world.scan_mm(T_base_tcp, rng, elapsed_s=elapsed)
        ranges_m = np.where(raw_mm >= round(world.geometry.min_range_m * 1000.0), raw_mm / 1000.0, np.nan)
        out.append(LaserScan(
            sequence=k, geometry=world.geometry, ranges_m=ranges_m, raw_ranges_mm=raw_mm,
            intensities=intensities, device_time_s=k * period_s, host_time_s=k * period_s,
        ))
    return out
