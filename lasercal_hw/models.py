"""Plain value types that cross module boundaries (see docs/architecture.md, "The data flow").

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
    #: A twist drill: its section has two flutes, not a circle (``find_rod_centre(fluted=)``).
    fluted: bool = False

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
    #: The part of ``covariance_uv_m2`` another dwell at this pose draws anew
    #: (``RodCentre.dwell_noise_covariance_uv_m2``); None: unknown.
    noise_covariance_uv_m2: FloatArray | None = None


@dataclass(frozen=True)
class RobotCalibration:
    """The robot controller's own kinematics calibration, as its primary client interface
    reports it (docs/ur.md): one checksum per joint and the calibrated DH rows (nominal
    table plus the factory's corrections), with the model and software it came from."""

    checksums: tuple[int, ...]
    dh_theta_rad: tuple[float, ...]
    dh_a_m: tuple[float, ...]
    dh_d_m: tuple[float, ...]
    dh_alpha_rad: tuple[float, ...]
    calibration_status: int
    #: ``UR5``, ``UR5e``, ``UR10e``, ... (robot type and software generation), or ``unknown``.
    model: str
    software_version: str

    @property
    def checksum(self) -> str:
        """The six joint checksums as one hex word per joint, ``-`` between them."""
        return "-".join(f"{value:08x}" for value in self.checksums)

    def as_dict(self) -> dict[str, object]:
        """The JSON form recorded with a calibration and a verify."""
        return {
            "checksum": self.checksum, "checksums": list(self.checksums),
            "dh_theta_rad": list(self.dh_theta_rad), "dh_a_m": list(self.dh_a_m),
            "dh_d_m": list(self.dh_d_m), "dh_alpha_rad": list(self.dh_alpha_rad),
            "calibration_status": self.calibration_status, "model": self.model,
            "software_version": self.software_version,
        }

    @classmethod
    def from_dict(cls, record: dict[str, object]) -> RobotCalibration:
        """The inverse of ``as_dict`` (KeyError, TypeError or ValueError on a bad record)."""
        def floats(key: str) -> tuple[float, ...]:
            return tuple(float(v) for v in record[key])  # type: ignore[attr-defined]

        return cls(
            checksums=tuple(int(v) for v in record["checksums"]),  # type: ignore[attr-defined]
            dh_theta_rad=floats("dh_theta_rad"), dh_a_m=floats("dh_a_m"), dh_d_m=floats("dh_d_m"),
            dh_alpha_rad=floats("dh_alpha_rad"), calibration_status=int(record["calibration_status"]),  # type: ignore[arg-type]
            model=str(record["model"]), software_version=str(record["software_version"]),
        )

    def change_from(self, recorded: RobotCalibration) -> str | None:
        """None when this is the calibration ``recorded``; else what changed, in words."""
        if self.checksums != recorded.checksums:
            return f"checksum {recorded.checksum} -> {self.checksum}"
        rows = ("dh_theta_rad", "dh_a_m", "dh_d_m", "dh_alpha_rad")
        pairs = (zip(getattr(self, row), getattr(recorded, row), strict=True) for row in rows)
        largest = max(abs(a - b) for row in pairs for a, b in row)
        if largest > DH_SAME_TOLERANCE:
            return f"same checksum {self.checksum}, but a DH value moved by {largest:.3g}"
        return None


#: DH values closer than this (m or rad) are the same calibration (they travel as doubles).
DH_SAME_TOLERANCE = 1e-9
