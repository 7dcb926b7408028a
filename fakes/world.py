"""The fake cell's simulated world: what the fake scanner sees while the fake robot moves.

The scanner sits at a ground-truth pose in the robot base frame; each of its beams is a
ray in the scan plane, intersected exactly in 3D with the rod (a finite cylinder held at
the TCP), the robot's base column, the walls and the floor.  The scene's ``model`` picks
what the scanner makes of that: ``physical`` (the default: a real UTM-30LX-EW's
footprint, echo, intensity, noise, bias and warm-up drift, ``fakes/scanner_model``,
docs/scanner-model.md) or ``ideal`` (exact rays plus the ``[noise]`` settings: gaussian
noise, bias, flipping mixed pixels, dropouts; docs/extraction.md).  The robot's
absolute-accuracy error applies to both.

The static part of the scene is cast once when the world is built; a scan only casts
the rod, so a 1081-beam scan costs a fraction of a millisecond.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fakes.raycast import beams_near_sphere
from fakes.scanner_model.physical import MovingShape, PhysicalScanner
from fakes.scene import NoiseSettings, Scene, load_scene
from fakes.shapes import Shape
from lasercal_hw.geometry import (
    euler_zyx_to_matrix,
    invert_transform,
    make_transform,
    pose_to_matrix,
    rotvec_to_matrix,
)
from lasercal_hw.models import FloatArray, RodLine, ScanGeometry

logger = logging.getLogger(__name__)

NO_RETURN_CODE = 1
"""UTM-30LX error code "no object in the range": no return within DMAX."""
DROPOUT_CODE = 3
"""UTM-30LX error code "measurement error": a reading lost at random."""
TOO_NEAR_CODE = 4
"""UTM-30LX error code "object out of range (at the near end)": nearer than DMIN."""

_SUB_RAYS = 5
_INTENSITY_SCALE = 10000.0
_INTENSITY_HALF_RANGE_M = 3.0
_INTENSITY_NOISE = 0.02


class RobotErrorField:
    """Absolute-accuracy error of the robot: a smooth, repeatable function of the pose.

    A real arm's error comes from its kinematic parameters, so it changes smoothly with
    the configuration and repeats when the arm returns to a pose.  Modelled as a sum of
    random sinusoids of the TCP position and orientation (wavelength about half a metre
    or radian), scaled so each translation axis has RMS ``position_m`` and each rotation
    axis RMS ``rotation_rad`` over poses.
    """

    _COMPONENTS = 6
    _WAVELENGTH = 0.5

    def __init__(self, position_m: float, rotation_rad: float, seed: int) -> None:
        rng = np.random.default_rng(seed)
        k = self._COMPONENTS
        self._wavevectors = rng.normal(0.0, 2.0 * np.pi / self._WAVELENGTH, (k, 9))
        self._phases = rng.uniform(0.0, 2.0 * np.pi, k)
        scale = np.sqrt(2.0 / k) * np.array([position_m] * 3 + [rotation_rad] * 3)
        self._amplitudes = rng.normal(0.0, 1.0, (k, 6)) * scale
        self.enabled = position_m > 0.0 or rotation_rad > 0.0
        self._last: tuple[bytes, FloatArray] | None = None  # a dwell asks for one pose many times

    def true_pose(self, T_base_tcp_reported: FloatArray) -> FloatArray:
        """The pose the TCP really has when the controller reports ``T_base_tcp_reported``."""
        T = np.asarray(T_base_tcp_reported, dtype=float)
        if not self.enabled:
            return T
        key = T.tobytes()
        if self._last is None or self._last[0] != key:
            features = np.concatenate([T[:3, 3], T[:3, 2], T[:3, 0]])
            delta = np.sin(self._wavevectors @ features + self._phases) @ self._amplitudes
            self._last = (key, make_transform(rotvec_to_matrix(delta[3:]) @ T[:3, :3], T[:3, 3] + delta[:3]))
        return self._last[1].copy()


class World:
    """The simulated cell: scanner pose, rod, walls, floor, noise; casts scans."""

    def __init__(self, scene: Scene, scanner: str | None = None) -> None:
        """The world as ``scanner`` sees it (default: the scene's first scanner)."""
        scene = scene.for_scanner(scanner or scene.scanner_names()[0])
        self.scene = scene
        s = scene.scanner
        self.geometry = ScanGeometry(
            first_step=s.first_step,
            last_step=s.last_step,
            cluster=1,
            front_step=s.front_step,
            steps_per_revolution=s.steps_per_revolution,
            min_range_m=s.min_range_m,
            max_range_m=s.max_range_m,
            scan_period_s=s.scan_period_s,
        )
        yaw, pitch, roll = np.radians(s.euler_zyx_deg)
        self._T_base_laser = make_transform(euler_zyx_to_matrix(yaw, pitch, roll), s.translation_m)
        self._T_laser_base = invert_transform(self._T_base_laser)
        r = scene.rod
        self._rod = RodLine(
            origin_m=np.asarray(r.origin_m, dtype=float),
            direction=np.asarray(r.direction, dtype=float),
            radius_m=r.radius_m,
            length_m=r.length_m,
        )
        self.angles_rad = self.geometry.angles_rad()
        self._dirs = _beam_dirs(self.angles_rad)
        half = np.radians(scene.noise.beam_footprint_deg) / 2.0
        offsets = np.linspace(-half, half, _SUB_RAYS)
        self._sub_dirs = _beam_dirs(self.angles_rad[:, None] + offsets[None, :])
        R, t = self._T_laser_base[:3, :3], self._T_laser_base[:3, 3]
        self._static = [shape.moved(R, t) for shape in _static_shapes(scene)]
        self.physical: PhysicalScanner | None = None
        if scene.model == "physical":
            self.physical = PhysicalScanner(scene.physics, self.angles_rad, self._static)
        else:
            self._static_t, self._static_cos, self._static_refl = self._cast(self._static, self._dirs)
            sub_flat = self._sub_dirs.reshape(-1, 3)
            self._static_sub_t = self._cast(self._static, sub_flat)[0].reshape(-1, _SUB_RAYS)
        n = scene.noise
        self.robot_error = RobotErrorField(
            n.robot_position_error_m, np.radians(n.robot_rotation_error_deg), n.robot_error_seed
        )

    @classmethod
    def from_scene(cls, path: str | Path | None = None) -> World:
        """Build the world of a scene file; ``None`` uses the packaged default scene."""
        return cls(load_scene(path))

    @property
    def ground_truth_T_base_laser(self) -> FloatArray:  # noqa: N802 (name fixed by the interface)
        """The scanner's true pose in the base frame (4x4), what calibration should find."""
        return self._T_base_laser.copy()

    @property
    def rod(self) -> RodLine:
        """The rod's axis in the TCP frame, its radius and length."""
        return self._rod

    @staticmethod
    def _cast(shapes: list[Shape], dirs: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Nearest hit over shapes: distance, |cos incidence| and reflectivity per ray."""
        best_t = np.full(dirs.shape[0], np.inf)
        best_cos = np.zeros(dirs.shape[0])
        best_refl = np.zeros(dirs.shape[0])
        for shape in shapes:
            t, cos = shape.hit(dirs)
            nearer = t < best_t
            if not nearer.any():
                continue
            best_t = np.where(nearer, t, best_t)
            best_cos = np.where(nearer, cos, best_cos)
            best_refl = np.where(nearer, shape.reflectivity, best_refl)
        return best_t, best_cos, best_refl

    def rod_shape_in_scanner(self, T_base_tcp: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Rod axis start point and unit direction in the scanner frame for a *true* TCP pose."""
        T_laser_tcp = self._T_laser_base @ np.asarray(T_base_tcp, dtype=float)
        point = T_laser_tcp[:3, :3] @ self._rod.origin_m + T_laser_tcp[:3, 3]
        return point, T_laser_tcp[:3, :3] @ self._rod.unit_direction()

    def _rod_shape(self, T_base_tcp_true: FloatArray) -> Shape:
        point, axis = self.rod_shape_in_scanner(T_base_tcp_true)
        scalars = (self._rod.radius_m, 0.0, self._rod.length_m)
        return Shape("cylinder", (point, axis), scalars, self.scene.rod.reflectivity, self.scene.rod.material)

    def _moving_shapes(self, T_base_tcp_true: FloatArray) -> list[MovingShape]:
        """The rod (a cylinder or a fluted twist drill) and its chuck, each with a
        bounding sphere, in the scanner frame (physical model)."""
        rod = self.scene.rod
        point, axis = self.rod_shape_in_scanner(T_base_tcp_true)
        bit = self._rod_shape(T_base_tcp_true)
        if rod.shape == "twist_drill":
            T_laser_tcp = self._T_laser_base @ np.asarray(T_base_tcp_true, dtype=float)
            ref = T_laser_tcp[:3, 0] - (T_laser_tcp[:3, 0] @ axis) * axis
            if np.linalg.norm(ref) < 1e-9:  # rod along the TCP x axis: use TCP y
                ref = T_laser_tcp[:3, 1] - (T_laser_tcp[:3, 1] @ axis) * axis
            ref = rotvec_to_matrix(axis * np.radians(rod.chuck_turn_deg)) @ ref  # the bit's turn in its chuck
            lead = rod.helix_lead_m or np.pi * 2.0 * rod.radius_m / np.tan(np.radians(30.0))
            scalars = (rod.radius_m, 0.0, rod.length_m, rod.web_fraction, lead)
            params = (point, axis, ref / np.linalg.norm(ref))
            bit = Shape("drill", params, scalars, rod.reflectivity, rod.material)
        moving: list[MovingShape] = [(bit, *_in_plane_bound(point, axis, rod.radius_m, 0.0, rod.length_m))]
        if rod.chuck_radius_m > 0.0:
            limits = (rod.chuck_radius_m, -rod.chuck_length_m, 0.0)
            chuck = Shape("cylinder", (point, axis), limits, rod.reflectivity, rod.chuck_material)
            bound = _in_plane_bound(point, axis, rod.chuck_radius_m, -rod.chuck_length_m, 0.0)
            moving.append((chuck, *bound))
        return moving

    def _trace(
        self,
        T_base_tcp: FloatArray,
        rng: np.random.Generator | None,
        apply_robot_error: bool,
        elapsed_s: float | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """Ranges (inf: no return, NaN: dropout) and intensities (ideal: arbitrary units;
        physical: the device's)."""
        T_true = self.robot_error.true_pose(T_base_tcp) if apply_robot_error else np.asarray(T_base_tcp)
        if self.physical is not None:
            ranges, intensity = self.physical.scan(self._moving_shapes(T_true), rng, elapsed_s)
            return np.where(ranges > self.geometry.max_range_m, np.inf, ranges), intensity
        rod = self._rod_shape(T_true)
        ranges, cos, refl = self._static_t.copy(), self._static_cos.copy(), self._static_refl.copy()
        beams = self._rod_beams(rod)
        if beams.size:
            rod_t, rod_cos, _ = self._cast([rod], self._dirs[beams])
            nearer = rod_t < ranges[beams]
            hit = beams[nearer]
            ranges[hit], cos[hit], refl[hit] = rod_t[nearer], rod_cos[nearer], rod.reflectivity
        intensity = refl * cos * _INTENSITY_SCALE / (1.0 + (ranges / _INTENSITY_HALF_RANGE_M) ** 2)
        if rng is not None:
            noise = self.scene.noise
            ranges = self._mixed_pixels(ranges, rod, beams, noise, rng)
            finite = np.isfinite(ranges)
            measured = ranges[finite]
            noise_m = rng.normal(0.0, 1.0, measured.size) * _sigma_m(measured, noise)
            ranges[finite] = measured + _bias_m(measured, noise) + noise_m
            intensity = intensity * (1.0 + _INTENSITY_NOISE * rng.normal(0.0, 1.0, ranges.size))
            ranges = np.where(rng.random(ranges.size) < noise.dropout_probability, np.nan, ranges)
        ranges = np.where(ranges > self.geometry.max_range_m, np.inf, ranges)
        intensity = np.where(np.isfinite(ranges), np.fmax(intensity, 0.0), 0.0)
        return ranges, intensity

    def _rod_beams(self, rod: Shape) -> NDArray[np.int64]:
        """Indices of the beams that can touch the rod (its bounding sphere), before exact casting."""
        point, axis = rod.params
        half_length = 0.5 * self._rod.length_m
        bound_m = float(np.hypot(half_length, self._rod.radius_m))
        return beams_near_sphere(self.angles_rad, point + half_length * axis, bound_m)

    def _mixed_pixels(
        self,
        ranges: FloatArray,
        rod: Shape,
        rod_beams: NDArray[np.int64],
        noise: NoiseSettings,
        rng: np.random.Generator,
    ) -> FloatArray:
        """Beams whose footprint straddles a depth edge may return a blend of both depths;
        ``rod_beams`` are the beams that can touch the rod (``_rod_beams``)."""
        if noise.mixed_pixel_probability <= 0.0 or noise.beam_footprint_deg <= 0.0:
            return ranges
        with np.errstate(invalid="ignore"):
            step = np.abs(np.diff(ranges))
        jump = ~(step <= noise.edge_jump_m)  # inf - inf is NaN: not a jump
        jump &= ~(np.isinf(ranges[:-1]) & np.isinf(ranges[1:]))
        near_edge = np.concatenate([[False], jump]) | np.concatenate([jump, [False]])
        beams = np.flatnonzero(near_edge)
        if beams.size == 0:
            return ranges
        sub_t = self._static_sub_t[beams].copy()
        near_rod = np.intersect1d(beams, rod_beams, assume_unique=True)
        if near_rod.size:
            rows = np.searchsorted(beams, near_rod)
            rod_t = rod.intersect(self._sub_dirs[near_rod].reshape(-1, 3)).reshape(-1, _SUB_RAYS)
            sub_t[rows] = np.fmin(sub_t[rows], rod_t)
        near_t, far_t = np.min(sub_t, axis=1), np.max(sub_t, axis=1)
        with np.errstate(invalid="ignore"):  # inf - inf where no sub-ray returns
            straddles = np.isfinite(near_t) & (far_t - near_t > noise.edge_jump_m)
        # A sub-ray belongs to the foreground when nearer than the middle of the gap; an
        # infinite background (no return) is never foreground.
        split = np.where(np.isfinite(far_t), 0.5 * (near_t + far_t), near_t + noise.edge_jump_m)
        is_near = sub_t <= split[:, None]
        fraction = is_near.mean(axis=1)
        near_mean = np.where(is_near, sub_t, 0.0).sum(axis=1) / np.maximum(is_near.sum(axis=1), 1)
        far_mean = np.where(is_near, 0.0, sub_t).sum(axis=1) / np.maximum((~is_near).sum(axis=1), 1)
        blend = fraction * near_mean + (1.0 - fraction) * far_mean
        majority = np.where(fraction >= 0.5, near_mean, far_mean)
        mixes = (rng.random(beams.size) < noise.mixed_pixel_probability) & np.isfinite(blend)
        value = np.where(mixes, blend, majority)
        out = ranges.copy()
        out[beams] = np.where(straddles, value, ranges[beams])
        return out

    def scan_ranges_m(
        self,
        T_base_tcp: FloatArray,
        rng: np.random.Generator | None = None,
        *,
        apply_robot_error: bool = True,
        elapsed_s: float | None = None,
    ) -> FloatArray:
        """One scan's ranges in metres for the TCP pose the controller reports.

        ``inf`` where no object lies within DMAX, ``NaN`` for a dropout.  With
        ``rng=None`` the scan is noise-free (ideal model: no noise, bias, mixed pixels or
        dropouts; physical model: no random part, but the footprint's mixed pixels and the
        bias stay); the robot's absolute-accuracy error is a property of the world and
        applies unless ``apply_robot_error`` is False.  ``elapsed_s``: time since the
        scanner's power-on, for the physical model's warm-up drift (None: warm).
        """
        return self._trace(T_base_tcp, rng, apply_robot_error, elapsed_s)[0]

    def scan_mm(
        self,
        T_base_tcp: FloatArray,
        rng: np.random.Generator | None = None,
        *,
        apply_robot_error: bool = True,
        elapsed_s: float | None = None,
    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """One scan as the scanner sends it: ranges in mm with error codes, and intensities."""
        ranges, intensity = self._trace(T_base_tcp, rng, apply_robot_error, elapsed_s)
        return to_wire_mm(ranges, self.geometry), np.round(intensity).astype(np.int64)


def to_wire_mm(ranges_m: FloatArray, geometry: ScanGeometry) -> NDArray[np.int64]:
    """Ranges in whole mm with the UTM-30LX error codes for no return, dropout, too near."""
    with np.errstate(invalid="ignore"):
        mm = np.round(np.where(np.isfinite(ranges_m), ranges_m, 0.0) * 1000.0).astype(np.int64)
    dmin_mm = round(geometry.min_range_m * 1000.0)
    mm = np.where(mm < dmin_mm, TOO_NEAR_CODE, mm)
    mm = np.where(np.isinf(ranges_m), NO_RETURN_CODE, mm)
    return np.where(np.isnan(ranges_m), DROPOUT_CODE, mm)


class WorldRangeSource:
    """Adapts a world to the fake scanner's ``RangeSource`` protocol (``fakes/scan_scene.py``).

    ``tcp_pose_at(time_s)`` returns the TCP pose (4x4, or a UR pose vector) the fake robot
    reports at that time.  The noise of each scan is seeded by ``seed`` and the scan's
    start time, so the same time always gives the same scan.  ``power_on_s`` is when the
    scanner was switched on, on the same clock (None: at the first scan), for the physical
    model's warm-up drift.
    """

    def __init__(
        self,
        world: World,
        tcp_pose_at: Callable[[float], FloatArray],
        seed: int = 0,
        power_on_s: float | None = None,
    ) -> None:
        self._world = world
        self._tcp_pose_at = tcp_pose_at
        self._seed = seed
        self._power_on_s = power_on_s

    def ranges_mm(self, time_s: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Distances (mm, error codes below DMIN) and intensities of every step of the scan
        starting at ``time_s``."""
        pose = np.asarray(self._tcp_pose_at(time_s), dtype=float)
        if pose.shape == (6,):
            pose = pose_to_matrix(pose)
        rng = np.random.default_rng([self._seed, round(time_s * 1e6)])
        if self._power_on_s is None:
            self._power_on_s = time_s
        return self._world.scan_mm(pose, rng, elapsed_s=time_s - self._power_on_s)


def _in_plane_bound(
    point: FloatArray, axis: FloatArray, radius_m: float, s_min: float, s_max: float
) -> tuple[FloatArray, float]:
    """A sphere holding every point of a solid cylinder (axis ``point + s axis``, ``s`` in
    [s_min, s_max]) that lies in the scan plane z = 0: such a point is within ``radius_m``
    of an axis point with |z| <= radius_m, so only that part of the axis counts (radius 0
    when the cylinder does not reach the plane)."""
    if abs(axis[2]) > 1e-12:
        ends = sorted(((-radius_m - point[2]) / axis[2], (radius_m - point[2]) / axis[2]))
        low, high = max(s_min, ends[0]), min(s_max, ends[1])
    elif abs(point[2]) <= radius_m:
        low, high = s_min, s_max
    else:
        low, high = 1.0, 0.0
    if low > high:
        return np.array([0.0, 0.0, 1e9]), 0.0
    half = 0.5 * (high - low)
    return point + 0.5 * (low + high) * axis, float(np.hypot(half, radius_m))


def _beam_dirs(angles_rad: FloatArray) -> FloatArray:
    return np.stack([np.cos(angles_rad), np.sin(angles_rad), np.zeros_like(angles_rad)], axis=-1)


def _sigma_m(ranges: FloatArray, noise: NoiseSettings) -> FloatArray:
    return np.where(ranges > noise.far_from_m, noise.range_sigma_far_m, noise.range_sigma_m)


def _bias_m(ranges: FloatArray, noise: NoiseSettings) -> FloatArray:
    """Smooth range bias at finite ranges."""
    bias = noise.bias_offset_m + noise.bias_per_m * ranges
    if noise.bias_ripple_m:
        bias = bias + noise.bias_ripple_m * np.sin(2.0 * np.pi * ranges / noise.bias_ripple_period_m)
    return bias


def _static_shapes(scene: Scene) -> list[Shape]:
    """Walls, floor, posts and base column in the base frame."""
    shapes = []
    for wall in scene.walls:
        start = np.array([*wall.start_m, wall.z_min_m])
        along = np.array([wall.end_m[0] - wall.start_m[0], wall.end_m[1] - wall.start_m[1], 0.0])
        up = np.array([0.0, 0.0, wall.z_max_m - wall.z_min_m])
        shapes.append(Shape("rectangle", (start, along, up), (), wall.reflectivity, wall.material))
    if scene.floor.enabled:
        plane = (np.array([0.0, 0.0, scene.floor.z_m]), np.array([0.0, 0.0, 1.0]))
        shapes.append(Shape("plane", plane, (), scene.floor.reflectivity, scene.floor.material))
    for post in scene.posts:
        axis = (np.array([*post.centre_m, 0.0]), np.array([0.0, 0.0, 1.0]))
        limits = (post.radius_m, post.z_min_m, post.z_max_m)
        shapes.append(Shape("cylinder", axis, limits, post.reflectivity, post.material))
    if scene.column.enabled:
        column = scene.column
        axis = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
        limits = (column.radius_m, 0.0, column.height_m)
        shapes.append(Shape("cylinder", axis, limits, column.reflectivity, column.material))
    return shapes
