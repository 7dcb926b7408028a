"""Plain value types that cross module boundaries (see design.md, "Data flow").

Arrays travel in dataclasses; documents that are written to disk or validated from
user input are pydantic models next to the code that owns them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ScannerIdentity:
    """What the scanner says about itself (SCIP VV/PP)."""

    vendor: str
    product: str
    firmware: str
    protocol: str
    serial: str
    model: str


@dataclass(frozen=True)
class ScanGeometry:
    """Beam layout of a scan, from the scanner's PP parameters and the requested steps.

    Beam ``k`` covers steps ``first_step + k*cluster ...``; its angle is
    ``(step - front_step) * 2*pi / steps_per_revolution`` in the scanner frame
    (x towards the front step, y to the left, z up).
    """

    first_step: int
    last_step: int
    cluster: int
    front_step: int
    steps_per_revolution: int
    min_range_m: float
    max_range_m: float
    scan_period_s: float

    @property
    def beam_count(self) -> int:
        """Number of values per scan."""
        return -(-(self.last_step - self.first_step + 1) // max(self.cluster, 1))

    @property
    def angle_min_rad(self) -> float:
        """Angle of the first beam (the first of ``angles_rad``, without building them all)."""
        cluster = max(self.cluster, 1)
        step = self.first_step + (cluster - 1) / 2.0
        return (step - self.front_step) * (2.0 * np.pi / self.steps_per_revolution)

    @property
    def angle_increment_rad(self) -> float:
        """Angle between neighbouring beams (one cluster of steps)."""
        return max(self.cluster, 1) * 2.0 * np.pi / self.steps_per_revolution

    def angles_rad(self) -> FloatArray:
        """Beam angles in radians (centre of each cluster)."""
        cluster = max(self.cluster, 1)
        steps = self.first_step + cluster * np.arange(self.beam_count) + (cluster - 1) / 2.0
        return (steps - self.front_step) * (2.0 * np.pi / self.steps_per_revolution)


@dataclass(frozen=True)
class LaserScan:
    """One scan as the product uses it.

    ``ranges_m`` holds NaN where the scanner reported an error code or a value outside
    [DMIN, DMAX]; ``raw_ranges_mm`` keeps what was on the wire (error codes included) so
    a recording loses nothing.
    """

    sequence: int
    geometry: ScanGeometry
    ranges_m: FloatArray
    raw_ranges_mm: NDArray[np.int64]
    intensities: NDArray[np.int64] | None
    device_time_s: float
    host_time_s: float

    @property
    def valid(self) -> NDArray[np.bool_]:
        """True where the range is a measurement."""
        return np.isfinite(self.ranges_m)


@dataclass(frozen=True)
class RobotIdentity:
    """What the controller says about itself."""

    model: str
    serial_number: str
    software_version: str
    controller_version: tuple[int, int, int, int]


@dataclass(frozen=True)
class RobotState:
    """Modes that decide whether the robot may move."""

    robot_mode: str
    safety_status: str
    program_running: bool
    remote_control: bool
    protective_stop: bool
    emergency_stop: bool


@dataclass(frozen=True)
class RodLine:
    """The rod (or drill) axis in the TCP frame: ``p(s) = origin_m + s * direction``."""

    origin_m: FloatArray = field(default_factory=lambda: np.zeros(3))
    direction: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    radius_m: float = 0.02
    length_m: float = 0.3

    def unit_direction(self) -> FloatArray:
        """The axis direction normalised to length one."""
        d = np.asarray(self.direction, dtype=float)
        return d / np.linalg.norm(d)

    def end_points_m(self) -> FloatArray:
        """The rod's two ends (origin, tip) in the TCP frame, shape (2, 3)."""
        origin = np.asarray(self.origin_m, dtype=float)
        return np.stack([origin, origin + self.length_m * self.unit_direction()])


@dataclass(frozen=True)
class Observation:
    """One waypoint's measurement: where the robot says the TCP is, and where the
    scanner saw the rod centre in its own plane."""

    index: int
    tcp_pose: FloatArray
    centre_uv_m: FloatArray
    covariance_uv_m2: FloatArray | None = None
