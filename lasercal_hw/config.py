"""The job file: everything a calibration run needs besides the devices themselves.

A job file is TOML (see ``examples/rod.toml``); every table is optional and every field
has a default sized for the paper's setup (UR5, UTM-30LX-EW, a 20 mm rod on the flange).
Unknown keys are refused, and every error names the file and the field.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import euler_zyx_to_matrix, make_transform
from lasercal_hw.models import FloatArray, RodLine

Vector3 = Annotated[list[float], Field(min_length=3, max_length=3)]
PoseVector = Annotated[list[float], Field(min_length=6, max_length=6)]

DEFAULT_SCANNER_URL = "scip+tcp://192.168.0.10:10940"
DEFAULT_PRESET = "paper"
DEFAULT_SCANNER_NAME = "default"
"""The name of a job's one scanner when it gives ``[scanner]`` (or nothing) rather than
``[scanners.NAME]`` tables: a one-scanner job of today is a cell of the scanner ``default``."""
# A name goes into ROS 2 topic names (/scan/NAME) and frames (laser_NAME), which allow only
# letters, digits and underscores (ROS 2 design article 140, rmw_validate_full_topic_name).
SCANNER_NAME_PATTERN = r"^[a-z][a-z0-9_]{0,31}$"


class _Strict(BaseModel):
    # nan and inf are refused as what they are ("should be a finite number"), not
    # reported against whichever bound a nan comparison happens to fail first.
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class RobotConfig(_Strict):
    """Where the robot controller is (``--robot`` overrides ``host``), which model it is,
    and how far its reported TCP position may be from the real one."""

    host: str | None = None
    model: Literal["ur5", "ur5e"] | None = Field(
        None,
        description="robot model for offline kinematics (trajectory design and check); "
        "unset: the connected robot's model, or ur5 offline",
    )
    position_accuracy_mm: float = Field(
        1.0,
        ge=0.0,
        le=20.0,
        description="absolute positioning accuracy (RMS per axis) the solver's noise model assumes",
    )


class NominalPose(_Strict):
    """A rough guess of the scanner's mounting in the robot base frame (tape measure).

    Used to predict where the rod should appear in each scan; the solver never uses it.
    """

    translation_m: Vector3
    euler_zyx_deg: Vector3 = Field(default_factory=lambda: [0.0, 0.0, 0.0])

    def matrix(self) -> FloatArray:
        """The nominal ``T_base_laser`` as a 4x4 matrix."""
        yaw, pitch, roll = np.radians(self.euler_zyx_deg)
        return make_transform(euler_zyx_to_matrix(yaw, pitch, roll), self.translation_m)


def check_scanner_url(url: str) -> str:
    """``url`` when lasercal speaks its scheme (a ValueError saying which it speaks otherwise)."""
    if not url.startswith(("scip+tcp://", "scip+serial://")):
        raise ValueError("must start with scip+tcp:// or scip+serial://")
    return url


class ScannerConfig(_Strict):
    """How to reach the scanner (``--scanner`` overrides ``url``) and where it roughly is."""

    url: str = DEFAULT_SCANNER_URL
    timeout_s: float = Field(2.0, gt=0.0, le=60.0)
    nominal: NominalPose | None = None
    intensities: bool = Field(
        True,
        description="stream intensities with the ranges (SCIP ME instead of MD): the recording keeps them "
        "and the rod extraction tells a bright rod (retro-reflective tape) from the background-level mixed "
        "pixels beside it, places a plain rod across the bearing by its intensity's middle and tells a "
        "repeated step from a chance equal range; twice the bytes per scan (false: MD, ranges alone)",
    )
    estimate_range_offset: bool | Literal["auto"] = Field(
        "auto",
        description="estimate the scanner's range offset (measured minus true range) with the transform; "
        "auto: when the waypoints pin it down (a UTM-30LX may read tens of millimetres long, and an "
        "offset left out moves the result by as much)",
    )
    range_error_terms: int = Field(
        5,
        ge=1,
        le=5,
        description="most terms of the range error curve estimated: 1 an offset, each more a power of "
        "ln(distance / 1 m) (2 a slope, 3 a curvature, ...); each only where the waypoints pin it down and "
        "the data show it",
    )

    _known_scheme = field_validator("url")(check_scanner_url)


class RodConfig(_Strict):
    """The rod (or drill bit) axis in the TCP frame."""

    radius_m: float = Field(0.02, gt=0.0, le=0.2)
    length_m: float = Field(0.3, gt=0.0, le=2.0)
    origin_m: Vector3 = Field(default_factory=lambda: [0.0, 0.0, 0.0])
    direction: Vector3 = Field(default_factory=lambda: [0.0, 0.0, 1.0])
    estimate_axis: bool | Literal["auto"] = Field(
        False,
        description="estimate the line across (2) and its tilt (2) from origin_m/direction with the "
        "transform; "
        "auto: when the trajectory makes it observable",
    )
    axis_std_mm: float = Field(
        5.0,
        gt=0.0,
        le=100.0,
        description="how far the real axis may be off origin_m across itself (one std, mm): an estimated "
        "axis is held to it where the waypoints cannot see it",
    )
    axis_std_deg: float = Field(
        3.0, gt=0.0, le=45.0, description="how far the real axis may be tilted from direction (one std, deg)"
    )
    polished: bool = Field(
        False,
        description="the rod's surface is polished or ground metal (a steel drill bit): it returns the beam "
        "only where it faces the scanner square, so trajectory design leans it across the beam, not along, "
        "and keeps the robot's base from right behind it",
    )
    fluted: bool = Field(
        False,
        description="the rod is a twist drill: its section has two flutes and is no circle, so a centre "
        "found on it may lie off the axis by a part of the radius, depending on how the flutes face the "
        "scanner; the run estimates the flutes' phase with the transform and takes each centre's offset "
        "out where the tool's turns tell it, else the extraction puts it in the centre's covariance",
    )

    @field_validator("direction")
    @classmethod
    def _nonzero(cls, direction: list[float]) -> list[float]:
        if float(np.linalg.norm(direction)) < 1e-9:
            raise ValueError("must not be the zero vector")
        return direction

    def rod_line(self) -> RodLine:
        """The rod as the value type the extraction and the solver use."""
        return RodLine(
            origin_m=np.asarray(self.origin_m, dtype=float),
            direction=np.asarray(self.direction, dtype=float),
            radius_m=self.radius_m,
            length_m=self.length_m,
            fluted=self.fluted,
        )


class TrajectoryConfig(_Strict):
    """Which waypoints to visit: a named preset with parameters, or a waypoint file.

    A waypoint file is CSV with one UR pose per row (``x,y,z,rx,ry,rz``, metres and
    rotation vector in the base frame; a header row is allowed). A relative path is taken
    relative to the job file.
    """

    preset: str | None = None
    parameters: dict[str, float | int | str | bool | list[float]] = Field(default_factory=dict)
    waypoints_file: Path | None = None
    adaptive: bool = Field(
        False, description="design a short robust first part from scanner.nominal, solve, design the rest"
    )
    first_waypoints: int = Field(8, ge=6, le=100, description="adaptive: waypoints of the first design")
    design_waypoints: int = Field(20, ge=6, le=200, description="adaptive: waypoints in all")
    flute_phase_deg: float | None = Field(
        None,
        ge=0.0,
        lt=180.0,
        description="a twist drill (rod.fluted): the flute phase the waypoints were checked at (deg from the "
        "tool's x axis); the run first spins the bit at the first waypoint to find its own phase in the "
        "chuck, then turns every waypoint's tool about the bit by the difference (docs/solver.md)",
    )
    pose_uncertainty: tuple[float, float] = Field(
        (0.05, 5.0),
        description="how far off scanner.nominal may be (m, deg): the designs (trajectory design, adaptive) "
        "keep every crossing on the rod anywhere within it",
    )

    @model_validator(mode="before")
    @classmethod
    def _default_preset(cls, data: Any) -> Any:
        if isinstance(data, dict) and data.get("preset") is None and data.get("waypoints_file") is None:
            return {**data, "preset": DEFAULT_PRESET}
        return data

    @model_validator(mode="after")
    def _one_source(self) -> TrajectoryConfig:
        if self.waypoints_file is not None and self.preset is not None:
            raise ValueError("give either preset or waypoints_file, not both")
        if self.waypoints_file is not None and self.parameters:
            raise ValueError("parameters apply to a preset, not to a waypoints_file")
        if self.adaptive and self.waypoints_file is not None:
            raise ValueError("an adaptive run designs its own waypoints: leave out waypoints_file")
        if self.adaptive and self.first_waypoints >= self.design_waypoints:
            raise ValueError("first_waypoints must be fewer than design_waypoints")
        if self.adaptive and self.flute_phase_deg is not None:
            raise ValueError(
                "flute_phase_deg turns a waypoint file's or preset's tool turns; an adaptive run designs "
                "its own: leave out one of them"
            )
        return self


class SettleConfig(_Strict):
    """When the arm counts as steady after a move."""

    timeout_s: float = Field(10.0, gt=0.0, le=120.0)
    margin_s: float = Field(0.1, ge=0.0, le=5.0)
    max_drift_mm: float = Field(0.5, gt=0.0, le=50.0)


class AcquisitionConfig(_Strict):
    """How scans are gathered at each waypoint."""

    min_scan_fraction: float = Field(0.5, gt=0.0, le=1.0)
    max_missed_scans: int = Field(4, ge=0)
    max_attempts: int = Field(3, ge=1, le=10)
    scan_timeout_s: float = Field(5.0, gt=0.0, le=60.0)


class BackgroundConfig(_Strict):
    """The view of the cell without the rod, taken at a retract pose above the scan plane.

    ``pose`` is a UR pose; without it the first waypoint is lifted by ``lift_m`` (default:
    the rod length plus 5 cm) along the base z axis.
    """

    pose: PoseVector | None = None
    lift_m: float | None = Field(None, gt=0.0, le=1.5)
    scans: int = Field(40, ge=1, le=2000)


class MotionConfig(_Strict):
    """Speed and acceleration caps, and how to move between waypoints.

    ``joint`` (default) moves in joint space to each waypoint's preflight solution: no
    singularity on the way can stop it. ``linear`` moves the TCP on straight lines, which
    stay inside the (convex) workspace box but may pass near a singularity.
    """

    move: Literal["linear", "joint"] = "joint"
    speed_m_s: float = Field(0.10, gt=0.0, le=0.5)
    accel_m_s2: float = Field(0.30, gt=0.0, le=2.0)
    joint_speed_rad_s: float = Field(0.50, gt=0.0, le=1.5)
    joint_accel_rad_s2: float = Field(1.00, gt=0.0, le=4.0)


class WorkspaceConfig(_Strict):
    """Box in the robot base frame that the TCP and both rod ends must stay in; the one box
    that ``lasercal run``'s preflight and ``lasercal trajectory check`` both use."""

    min_m: Vector3 = Field(default_factory=lambda: [-0.95, -0.95, -0.10])
    max_m: Vector3 = Field(default_factory=lambda: [0.95, 0.95, 1.10])

    @model_validator(mode="after")
    def _ordered(self) -> WorkspaceConfig:
        for axis, low, high in zip("xyz", self.min_m, self.max_m, strict=True):
            if not low < high:
                raise ValueError(f"workspace box {axis}: min {low} m must be below max {high} m")
        return self

    def violations(self, point_m: FloatArray, what: str) -> list[str]:
        """Why ``point_m`` is outside the box, one reason per axis (empty when inside)."""
        reasons = []
        for axis, value, low, high in zip("xyz", np.asarray(point_m, dtype=float), self.min_m, self.max_m,
                                          strict=True):
            if value < low:
                reasons.append(f"{what} {axis} = {value:.3f} m is below the workspace minimum {low:.3f} m")
            elif value > high:
                reasons.append(f"{what} {axis} = {value:.3f} m is above the workspace maximum {high:.3f} m")
        return reasons


class QualityConfig(_Strict):
    """Gates a result must pass to be accepted (exit code 1 otherwise)."""

    max_rms_residual_mm: float = Field(10.0, gt=0.0)
    max_std_translation_mm: float = Field(10.0, gt=0.0)
    max_std_rotation_deg: float = Field(1.0, gt=0.0)
    max_outlier_fraction: float = Field(0.2, ge=0.0, le=1.0)
    min_observations: int = Field(8, ge=6)


class CellScannerConfig(ScannerConfig):
    """One of a cell's scanners (``[scanners.NAME]``): how to reach it, where it roughly is,
    and the rod, trajectory and quality gates where they differ from the job's."""

    rod: RodConfig | None = Field(
        None, description="the rod as this scanner sees it (default: the job's [rod])"
    )
    trajectory: TrajectoryConfig | None = Field(
        None, description="this scanner's waypoints (default: the job's [trajectory])"
    )
    quality: QualityConfig | None = Field(
        None, description="this scanner's gates (default: the job's [quality])"
    )

    def scanner_config(self) -> ScannerConfig:
        """The scanner fields alone, as a one-scanner job's ``[scanner]``."""
        fields = set(ScannerConfig.model_fields)
        return ScannerConfig.model_validate({k: v for k, v in self.model_dump().items() if k in fields})


class VerifyConfig(_Strict):
    """The drift check ``lasercal verify`` (docs/verify.md): how many waypoints, the
    false-alarm rate of its chi-square test, and the application tolerance that separates
    ``degraded`` (changed, still usable) from ``recalibrate``."""

    waypoints: int = Field(4, ge=2, le=20, description="waypoints visited (--waypoints overrides)")
    false_alarm_rate: float = Field(0.01, gt=0.0, lt=0.5, description="of the chi-square test")
    tolerance_mm: float = Field(2.0, gt=0.0, le=100.0, description="scanner shift still usable")
    tolerance_deg: float = Field(0.2, gt=0.0, le=10.0, description="scanner turn still usable")
    repeatability_mm: float = Field(
        0.1, ge=0.0, le=20.0, description="robot's return to a pose the calibration visited (RMS per axis)"
    )
    max_time_fraction: float = Field(
        0.25, gt=0.0, le=1.0, description="motion and dwell budget, as a share of the calibration's"
    )
    prior_shift_mm: float = Field(
        20.0, gt=0.0, le=1000.0, description="std of a plausible bump (prior of the correction)"
    )
    prior_turn_deg: float = Field(2.0, gt=0.0, le=90.0, description="std of a plausible bump's turn")


class OutputConfig(_Strict):
    """Where results go (``--out`` overrides ``dir``; default ``./lasercal-out/<timestamp>``)."""

    dir: Path | None = None
    report: bool = True


class JobConfig(_Strict):
    """A whole calibration job."""

    robot: RobotConfig = Field(default_factory=RobotConfig)
    scanner: ScannerConfig = Field(default_factory=ScannerConfig)
    rod: RodConfig = Field(default_factory=RodConfig)
    trajectory: TrajectoryConfig = Field(default_factory=TrajectoryConfig)
    dwell_s: float = Field(3.0, gt=0.0, le=60.0)
    settle: SettleConfig = Field(default_factory=SettleConfig)
    acquisition: AcquisitionConfig = Field(default_factory=AcquisitionConfig)
    background: BackgroundConfig = Field(default_factory=BackgroundConfig)
    motion: MotionConfig = Field(default_factory=MotionConfig)
    workspace: WorkspaceConfig = Field(default_factory=WorkspaceConfig)
    quality: QualityConfig = Field(default_factory=QualityConfig)
    verify: VerifyConfig = Field(default_factory=VerifyConfig)
    output: OutputConfig = Field(default_factory=OutputConfig)
    scanners: dict[str, CellScannerConfig] = Field(
        default_factory=dict,
        description="the cell's named scanners ([scanners.NAME]); without them the one [scanner] is "
        f"named {DEFAULT_SCANNER_NAME!r}",
    )

    @field_validator("scanners")
    @classmethod
    def _scanner_names(cls, scanners: dict[str, CellScannerConfig]) -> dict[str, CellScannerConfig]:
        for name in scanners:
            if not re.match(SCANNER_NAME_PATTERN, name):
                raise ValueError(
                    f"scanner name {name!r}: use a lower-case letter, then up to 31 of a-z, 0-9 and _ "
                    "(it names the ROS 2 topic /scan/NAME, where '-' is not allowed: "
                    f"e.g. {re.sub('[^a-z0-9_]', '_', name.lower())!r})"
                )
        return scanners

    @model_validator(mode="after")
    def _flute_phase_needs_a_fluted_rod(self) -> JobConfig:
        if self.trajectory.flute_phase_deg is None:
            return self
        if not self.rod.fluted:
            raise ValueError(
                "trajectory.flute_phase_deg is for a twist drill: set rod.fluted = true or leave it out"
            )
        if self.scanner.nominal is None and not self.scanners:
            raise ValueError(
                "trajectory.flute_phase_deg needs [scanner.nominal]: the spin's fit uses the scanner's rough "
                "pose to tell how the bit faces it"
            )
        return self

    @model_validator(mode="after")
    def _one_way_to_name_scanners(self) -> JobConfig:
        if self.scanners and self.scanner != ScannerConfig():
            raise ValueError("give either [scanner] (one scanner) or [scanners.NAME] tables, not both")
        return self

    def scanner_names(self) -> list[str]:
        """The cell's scanners in the job file's order (``default`` for a one-scanner job)."""
        return list(self.scanners) or [DEFAULT_SCANNER_NAME]

    def scanners_with_own_trajectory(self) -> list[str]:
        """The cell's scanners that visit their own entry's waypoints, not the job's [trajectory]."""
        return [name for name, entry in self.scanners.items() if entry.trajectory is not None]

    def for_scanner(self, name: str) -> JobConfig:
        """The one-scanner job of scanner ``name``: its ``[scanners.NAME]`` as ``[scanner]``, with
        its own rod, trajectory and gates where it gives them. A one-scanner job is itself."""
        if not self.scanners:
            if name != DEFAULT_SCANNER_NAME:
                raise ConfigError(
                    f"the job has one scanner, {DEFAULT_SCANNER_NAME!r}, not {name!r}: leave out the scanner "
                    "name or add [scanners.NAME] tables to the job file"
                )
            return self
        entry = self.scanners.get(name)
        if entry is None:
            raise ConfigError(f"the job has no scanner {name!r}; its scanners: {', '.join(self.scanners)}")
        return self.model_copy(update={
            "scanner": entry.scanner_config(),
            "rod": entry.rod or self.rod,
            "trajectory": entry.trajectory or self.trajectory,
            "quality": entry.quality or self.quality,
            "scanners": {},
        })

    def background_lift_m(self) -> float:
        """How far above the first waypoint the background is taken."""
        return self.background.lift_m if self.background.lift_m is not None else self.rod.length_m + 0.05


def _describe(exc: ValidationError, source: str) -> str:
    lines = []
    for error in exc.errors():
        field = ".".join(str(part) for part in error["loc"]) or "(top level)"
        message = error["msg"]
        if error["type"] == "extra_forbidden":
            message = "unknown field (check the spelling; see docs/sequencer.md for the fields)"
        lines.append(f"{source}: {field}: {message}")
    return "invalid job configuration:\n  " + "\n  ".join(lines)


def job_from_mapping(data: dict[str, Any], source: str = "job") -> JobConfig:
    """Validate a parsed job document; ``source`` names it in error messages."""
    try:
        return JobConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_describe(exc, source)) from None


def read_toml(path: Path, what: str) -> dict[str, Any]:
    """A TOML file as a dict; ConfigError naming ``what`` and the file when it cannot be read."""
    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{what} {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read {what} {path}: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None


def load_job(path: Path | None) -> JobConfig:
    """Read and validate a job file (``None``: all defaults).

    A relative ``trajectory.waypoints_file`` is resolved against the job file's folder.
    """
    if path is None:
        return JobConfig()
    return job_from_mapping(read_job_file(path), str(path))


def read_job_file(path: Path) -> dict[str, Any]:
    """A job file as a mapping, its relative ``waypoints_file`` (the job's and each
    ``scanners.NAME``'s) made absolute against the file's folder: what :func:`load_job`
    validates, and what a daemon request sends (validated there)."""
    data = read_toml(path, "job file")
    scanners = data.get("scanners") if isinstance(data.get("scanners"), dict) else {}
    entries = [entry for entry in scanners.values() if isinstance(entry, dict)]
    for table in [data, *entries]:
        trajectory = table.get("trajectory")
        if not (isinstance(trajectory, dict) and isinstance(trajectory.get("waypoints_file"), str)):
            continue
        if not Path(trajectory["waypoints_file"]).is_absolute():
            trajectory["waypoints_file"] = str((Path(path).parent / trajectory["waypoints_file"]).resolve())
    return data


def with_overrides(job: JobConfig, overrides: dict[str, Any], source: str = "command line") -> JobConfig:
    """A copy of ``job`` with dotted-key overrides (``{"scanner.url": ...}``), re-validated."""
    data = job.model_dump(mode="python")
    for dotted, value in overrides.items():
        if value is None:
            continue
        *parents, leaf = dotted.split(".")
        node = data
        for part in parents:
            if not isinstance(node.get(part), dict):
                node[part] = {}
            node = node[part]
        node[leaf] = value
    return job_from_mapping(data, source)
