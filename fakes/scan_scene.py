"""What the fake scanner sees: the ``RangeSource`` protocol and a default 2D scene.

A range source answers, for the revolution that starts at ``time_s``, the distances in
millimetres (values below DMIN = 23 are error codes) and the intensities of all steps
0..1080. The fake SCIP server cuts out the requested steps and clusters them itself. The default scene is a
rectangular room with one vertical cylinder (a 20 mm calibration rod by default),
ray-cast in the scan plane. The 3D world (``fakes/world.py``, ``WorldRangeSource``)
plugs in through the same protocol.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

STEP_COUNT = 1081
"""Steps 0..1080 of a UTM-30LX-EW (AMIN 0, AMAX 1080)."""
FRONT_STEP = 540
STEPS_PER_REVOLUTION = 1440
MIN_RANGE_MM = 23
MAX_RANGE_MM = 60000
NO_ECHO_CODE_MM = 1
"""Value sent for a beam that hits nothing in range (UTM-30LX table: 1 = no object in range)."""


class RangeSource(Protocol):
    """Anything that can tell the fake scanner what one revolution measures.

    One call per scan: ``time_s`` is the start of the revolution (seconds on the server's
    monotonic clock); the answer covers every step 0..1080, and the fake cuts out and
    clusters the steps a request asks for."""

    def ranges_mm(self, time_s: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Distances in mm (values < 23 are error codes) and received-light intensities
        (18-bit, unitless) of steps 0..1080."""
        ...


def beam_angles_rad() -> NDArray[np.float64]:
    """Angle of every step 0..1080 in the scanner frame (x forward, y left)."""
    return (np.arange(STEP_COUNT) - FRONT_STEP) * (2.0 * np.pi / STEPS_PER_REVOLUTION)


@dataclass(frozen=True)
class Cylinder:
    """A vertical cylinder crossing the scan plane at ``centre_m`` (scanner frame)."""

    centre_m: tuple[float, float]
    radius_m: float


@dataclass(frozen=True)
class RoomScene:
    """A rectangular room (axis-aligned walls) plus cylinders, seen from the origin.

    Intensity falls with range as ``intensity_at_1m / max(range_m, 0.1)``, clipped to
    the 18-bit field; ``noise_mm`` adds Gaussian range noise from a generator seeded by
    ``seed`` and the scan time, so the same time always gives the same scan.
    """

    x_min_m: float = -2.0
    x_max_m: float = 4.0
    y_min_m: float = -3.0
    y_max_m: float = 3.0
    cylinders: tuple[Cylinder, ...] = (Cylinder((1.5, 0.3), 0.020),)
    noise_mm: float = 0.0
    intensity_at_1m: float = 6000.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not (self.x_min_m < 0.0 < self.x_max_m and self.y_min_m < 0.0 < self.y_max_m):
            raise ValueError("the scanner (origin) must lie inside the room")

    def ranges_mm(self, time_s: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Distances (mm) and intensities of all steps 0..1080 at ``time_s``: every beam
        ray-cast against the walls and the cylinders (deterministic for a given time)."""
        angles = beam_angles_rad()
        dx, dy = np.cos(angles), np.sin(angles)
        distances = np.full(STEP_COUNT, np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            for bound, direction in (
                (self.x_min_m, dx), (self.x_max_m, dx), (self.y_min_m, dy), (self.y_max_m, dy)
            ):
                t = bound / direction
                distances = np.where((t > 0) & np.isfinite(t), np.minimum(distances, t), distances)
        for cylinder in self.cylinders:
            distances = np.minimum(distances, _ray_circle_m(dx, dy, cylinder))
        ranges = distances * 1000.0
        if self.noise_mm > 0.0:
            rng = np.random.default_rng([self.seed, round(time_s * 1e6) & 0xFFFFFFFF])
            ranges = ranges + rng.normal(0.0, self.noise_mm, STEP_COUNT)
        in_range = np.isfinite(ranges) & (ranges >= MIN_RANGE_MM) & (ranges <= MAX_RANGE_MM)
        ranges_mm = np.where(in_range, np.rint(np.where(in_range, ranges, 0.0)), NO_ECHO_CODE_MM)
        intensity = self.intensity_at_1m / np.maximum(np.where(in_range, ranges, 1e9) / 1000.0, 0.1)
        intensities = np.clip(np.rint(intensity), 0, (1 << 18) - 1)
        return ranges_mm.astype(np.int64), intensities.astype(np.int64)


def _ray_circle_m(
    dx: NDArray[np.float64], dy: NDArray[np.float64], cylinder: Cylinder
) -> NDArray[np.float64]:
    """Distance along unit rays from the origin to the first hit on the circle (inf if none)."""
    cx, cy = cylinder.centre_m
    along = dx * cx + dy * cy
    closest_sq = cx * cx + cy * cy - along * along
    half_chord_sq = cylinder.radius_m**2 - closest_sq
    hit = (half_chord_sq >= 0.0) & (along > 0.0)
    near = along - np.sqrt(np.where(hit, half_chord_sq, 0.0))
    return np.where(hit & (near > 0.0), near, np.inf)
