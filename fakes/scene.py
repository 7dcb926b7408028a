"""The fake cell's scene file (TOML): geometry, noise and fault settings, validated.

``load_scene(None)`` gives the packaged ``fakes/scenes/default.toml``; every field has a
default, so a scene file only lists what it changes.  docs/extraction.md describes the
format.  A bad file raises ``ConfigError`` naming the file, the field and the problem.
"""

from __future__ import annotations

import json
import math
import os
import tomllib
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from fakes.ur_controller.kinematics_calibration import DEFAULT_CHECKSUMS
from lasercal_hw.errors import ConfigError

Vector3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Vector2 = Annotated[list[float], Field(min_length=2, max_length=2)]
Probability = Annotated[float, Field(ge=0.0, le=1.0)]
Reflectivity = Annotated[float, Field(gt=0.0, le=1.0)]
Material = Literal["matte", "painted", "bare_metal", "steel_drill", "retro_tape", "dark"]
"""Surface materials of the physical scanner model (``fakes/scanner_model/materials.py``)."""
ModelName = Literal["physical", "ideal"]
"""``physical``: the UTM-30LX-EW model of ``fakes/scanner_model``; ``ideal``: exact ray
casting with the ``[noise]`` settings (gaussian noise, flipping mixed pixels)."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _non_zero(vector: list[float]) -> list[float]:
    if math.hypot(*vector) == 0.0:
        raise ValueError("must not be the zero vector")
    return vector


class ScannerSettings(_Strict):
    """Ground-truth pose and beam layout of the scanner (defaults: the paper, UTM-30LX-EW)."""

    translation_m: Vector3 = [0.30, 0.50, 0.20]
    euler_zyx_deg: Vector3 = [5.0, 7.0, 3.0]
    first_step: int = Field(0, ge=0)
    last_step: int = Field(1080, ge=0)
    front_step: int = Field(540, ge=0)
    steps_per_revolution: int = Field(1440, gt=0)
    min_range_m: float = Field(0.023, ge=0.0)
    max_range_m: float = Field(60.0, gt=0.0)
    scan_period_s: float = Field(0.025, gt=0.0)

    @model_validator(mode="after")
    def _steps_in_order(self) -> ScannerSettings:
        if self.last_step < self.first_step:
            raise ValueError(f"last_step ({self.last_step}) is before first_step ({self.first_step})")
        if self.max_range_m <= self.min_range_m:
            raise ValueError("max_range_m must be larger than min_range_m")
        return self


class RodSettings(_Strict):
    """The rod (or drill bit) on the flange: ``origin_m + s * direction``, s in [0, length_m]."""

    origin_m: Vector3 = [0.0, 0.0, 0.0]
    direction: Vector3 = [0.0, 0.0, 1.0]
    radius_m: float = Field(0.02, gt=0.0)
    length_m: float = Field(0.3, gt=0.0)
    reflectivity: Reflectivity = 0.8
    material: Material = "painted"
    shape: Literal["cylinder", "twist_drill"] = "cylinder"
    """``twist_drill``: the section has two flutes and a web (physical model only)."""
    web_fraction: float = Field(0.16, gt=0.0, lt=0.5)
    """Twist drill: web thickness over the diameter."""
    helix_lead_m: float = Field(0.0, ge=0.0)
    """Twist drill: axial length of one flute turn (0: a 30 deg helix, pi D / tan 30 deg, 5.4 diameters)."""
    chuck_turn_deg: float = 0.0
    """Twist drill: how far the bit sits turned in its chuck about its own axis (right-handed
    about ``direction``); at 0 the flutes' middles lie 90 deg from the TCP's x axis."""
    chuck_radius_m: float = Field(0.0, ge=0.0)
    """A chuck (collet nut) coaxial with the rod above it, ``s`` in [-chuck_length_m, 0]; 0 = none."""
    chuck_length_m: float = Field(0.05, gt=0.0)
    chuck_material: Material = "bare_metal"

    _direction_non_zero = field_validator("direction")(_non_zero)


class ColumnSettings(_Strict):
    """The robot's base as a vertical cylinder standing on the base origin."""

    enabled: bool = True
    radius_m: float = Field(0.075, gt=0.0)
    height_m: float = Field(0.25, gt=0.0)
    reflectivity: Reflectivity = 0.5
    material: Material = "painted"


def _check_height(kind: str, name: str, z_min_m: float, z_max_m: float) -> None:
    if z_max_m <= z_min_m:
        raise ValueError(f"{kind} {name!r}: z_max_m must be above z_min_m")


class WallSettings(_Strict):
    """A vertical wall between two floor points (base frame), from z_min_m to z_max_m."""

    name: str = "wall"
    start_m: Vector2
    end_m: Vector2
    z_min_m: float = 0.0
    z_max_m: float = 2.5
    reflectivity: Reflectivity = 0.7
    material: Material = "matte"

    @model_validator(mode="after")
    def _proper_rectangle(self) -> WallSettings:
        if self.start_m == self.end_m:
            raise ValueError(f"wall {self.name!r}: start_m and end_m are the same point")
        _check_height("wall", self.name, self.z_min_m, self.z_max_m)
        return self


class PostSettings(_Strict):
    """A vertical cylinder standing in the cell (a pole, a fixture leg): clutter the size of
    a rod, at ``centre_m`` (base frame), from ``z_min_m`` to ``z_max_m``."""

    name: str = "post"
    centre_m: Vector2
    radius_m: float = Field(0.02, gt=0.0)
    z_min_m: float = 0.0
    z_max_m: float = 2.0
    reflectivity: Reflectivity = 0.6
    material: Material = "painted"

    @model_validator(mode="after")
    def _proper_height(self) -> PostSettings:
        _check_height("post", self.name, self.z_min_m, self.z_max_m)
        return self


class FloorSettings(_Strict):
    """A horizontal plane (the floor or the table the robot stands on)."""

    enabled: bool = True
    z_m: float = 0.0
    reflectivity: Reflectivity = 0.4
    material: Material = "painted"


class NoiseSettings(_Strict):
    """Range noise, bias, mixed pixels, dropouts and the robot's absolute-accuracy error."""

    range_sigma_m: float = Field(0.010, ge=0.0)
    range_sigma_far_m: float = Field(0.030, ge=0.0)
    far_from_m: float = Field(10.0, gt=0.0)
    bias_offset_m: float = 0.0
    bias_per_m: float = 0.0
    bias_ripple_m: float = 0.0
    bias_ripple_period_m: float = Field(1.0, gt=0.0)
    beam_footprint_deg: float = Field(0.25, ge=0.0)
    edge_jump_m: float = Field(0.03, gt=0.0)
    mixed_pixel_probability: Probability = 0.5
    dropout_probability: Probability = 0.001
    robot_position_error_m: float = Field(0.00058, ge=0.0)  # per axis: 1.0 mm RMS in 3D
    robot_rotation_error_deg: float = Field(0.02, ge=0.0)
    robot_error_seed: int = 0


class PhysicsSettings(_Strict):
    """Parameters of the physical UTM-30LX-EW model; docs/scanner-model.md gives each one's source."""

    spot_width_at_scanner_m: float = Field(0.020, ge=0.0)
    divergence_rad: float = Field(0.011, ge=0.0)
    halo_fraction: float = Field(0.015, ge=0.0, lt=1.0)
    halo_scale: float = Field(2.5, ge=1.0)
    sub_rays: int = Field(21, ge=1, le=63)
    pulse_fwhm_m: float = Field(1.0, gt=0.0)
    echo_choice: Literal["strongest", "first"] = "strongest"
    intensity_at_1m: float = Field(3600.0, gt=0.0)
    overlap_range_m: float = Field(0.45, ge=0.0)
    detection_threshold: float = Field(100.0, ge=0.0)
    intensity_max: float = Field(40000.0, gt=0.0)
    speckle_sigma: float = Field(0.10, ge=0.0)
    intensity_noise: float = Field(0.008, ge=0.0)
    noise_floor_m: float = Field(0.0020, ge=0.0)
    noise_at_reference_m: float = Field(0.0028, ge=0.0)
    reference_intensity: float = Field(4000.0, gt=0.0)
    walk_m_per_efold: float = Field(0.0025, ge=0.0)
    walk_limit_m: float = Field(0.010, ge=0.0)
    near_bias_m: float = 0.020
    near_bias_at_m: float = Field(0.10, gt=0.0)
    near_bias_decay_m: float = Field(0.09, gt=0.0)
    unit_bias_m: float = Field(0.010, ge=0.0)
    unit_seed: int = 0
    bias_limit_m: float = Field(0.030, ge=0.0)
    warmup_drift_m: float = 0.010
    warmup_time_constant_s: float = Field(900.0, gt=0.0)
    warm_at_start: bool = True
    duplicate_step_probability: Probability = 0.28


class FaultSettings(_Strict):
    """Faults the fake devices inject (acted on by the fake robot and scanner)."""

    protective_stop_at_waypoint: int | None = Field(None, ge=0)
    scanner_drop_at_waypoint: int | None = Field(None, ge=0)
    corrupt_checksum_every_scans: int = Field(0, ge=0)
    scanner_stale_field: str = Field("", pattern=r"^([A-Z]{4}=[ -~]+)?$")
    """``"KEY=VALUE"``: the scanner's VV/PP/II line of KEY says VALUE under the old checksum."""


class RobotKinematicsSettings(_Strict):
    """The fake controller's own kinematics calibration, as its primary interface reports it:
    one checksum per joint and the corrections to the nominal UR5 DH rows (m, rad). Identity
    data only: the fake moves on the nominal model (docs/ur.md)."""

    checksums: list[int] = Field(default_factory=lambda: list(DEFAULT_CHECKSUMS), min_length=6, max_length=6)
    delta_theta_rad: list[float] = Field(default_factory=lambda: [0.0] * 6, min_length=6, max_length=6)
    delta_a_m: list[float] = Field(default_factory=lambda: [0.0] * 6, min_length=6, max_length=6)
    delta_d_m: list[float] = Field(default_factory=lambda: [0.0] * 6, min_length=6, max_length=6)
    delta_alpha_rad: list[float] = Field(default_factory=lambda: [0.0] * 6, min_length=6, max_length=6)

    @field_validator("checksums")
    @classmethod
    def _uint32(cls, checksums: list[int]) -> list[int]:
        if any(not 0 <= value < 1 << 32 for value in checksums):
            raise ValueError("each checksum is an unsigned 32-bit number (0 to 4294967295)")
        return checksums


def _default_walls() -> list[WallSettings]:
    corners = [(-1.5, -1.5), (2.5, -1.5), (2.5, 2.5), (-1.5, 2.5)]
    names = ["south", "east", "north", "west"]
    return [
        WallSettings(name=name, start_m=list(a), end_m=list(b))
        for name, a, b in zip(names, corners, corners[1:] + corners[:1], strict=True)
    ]


DEFAULT_SCANNER_NAME = "default"
"""The name of a scene's one ``[scanner]`` (as in a one-scanner job file)."""


class Scene(_Strict):
    """Everything the simulated world needs: one ``[scanner]``, or several ``[scanners.NAME]``
    in the same world (each its own SCIP endpoint in the fake cell)."""

    scanner: ScannerSettings = ScannerSettings()
    scanners: dict[str, ScannerSettings] = Field(default_factory=dict)
    rod: RodSettings = RodSettings()
    column: ColumnSettings = ColumnSettings()
    walls: list[WallSettings] = Field(default_factory=_default_walls)
    posts: list[PostSettings] = Field(default_factory=list)
    floor: FloorSettings = FloorSettings()
    model: ModelName = "physical"
    """Which scanner model casts the scans: switch the fake cell's default here and in
    ``fakes/scenes/default.toml``."""
    physics: PhysicsSettings = PhysicsSettings()
    noise: NoiseSettings = NoiseSettings()
    faults: FaultSettings = FaultSettings()
    robot_kinematics: RobotKinematicsSettings = RobotKinematicsSettings()

    @model_validator(mode="after")
    def _one_way_to_place_scanners(self) -> Scene:
        if self.scanners and self.scanner != ScannerSettings():
            raise ValueError("give either [scanner] (one scanner) or [scanners.NAME] tables, not both")
        return self

    def scanner_names(self) -> list[str]:
        """The scanners in the scene file's order (``default`` for a one-scanner scene)."""
        return list(self.scanners) or [DEFAULT_SCANNER_NAME]

    def for_scanner(self, name: str) -> Scene:
        """The one-scanner scene of scanner ``name``: the same world seen by that scanner."""
        if not self.scanners and name == DEFAULT_SCANNER_NAME:
            return self
        if name not in self.scanners:
            known = ", ".join(self.scanner_names())
            raise ConfigError(f"the scene has no scanner {name!r}; its scanners: {known}")
        return self.model_copy(update={"scanner": self.scanners[name], "scanners": {}})

    def to_toml(self) -> str:
        """The scene as a scene file (every field; unset optional ones left out), which
        ``parse_scene`` reads back to an equal scene."""
        data = self.model_dump(exclude_none=True)
        tables = {k: v for k, v in data.items() if isinstance(v, dict)}
        arrays = {k: v for k, v in data.items() if isinstance(v, list) and v and isinstance(v[0], dict)}
        lines = [f"{k} = {_toml_value(v)}" for k, v in data.items() if k not in tables and k not in arrays]
        for name, table in tables.items():
            lines += ["", f"[{name}]", *(f"{k} = {_toml_value(v)}" for k, v in table.items())]
        for name, items in arrays.items():
            for item in items:
                lines += ["", f"[[{name}]]", *(f"{k} = {_toml_value(v)}" for k, v in item.items())]
        return "\n".join(lines).lstrip("\n") + "\n"


def _toml_value(value: Any) -> str:
    """A TOML value: a boolean, a number, a string, or a list or inline table of them."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)  # full precision; inf and nan are TOML too
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a valid TOML basic string
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(v)}" for k, v in value.items()) + "}"
    return "[" + ", ".join(_toml_value(item) for item in value) + "]"


MODEL_ENV = "LASERCAL_FAKE_SCANNER_MODEL"
"""Environment variable that overrides the fake cell's scanner model (``ideal`` or
``physical``), whatever the scene says; the test suite sets it to ``ideal`` (its dry runs'
bounds were sized on that model: tests/conftest.py)."""


def with_model_override(scene: Scene) -> Scene:
    """``scene`` with its ``model`` replaced by ``$LASERCAL_FAKE_SCANNER_MODEL`` when set."""
    wanted = os.environ.get(MODEL_ENV, "").strip()
    if not wanted:
        return scene
    if wanted not in ("ideal", "physical"):
        raise ConfigError(f"{MODEL_ENV}={wanted!r} is not a scanner model; use ideal or physical or unset it")
    return scene.model_copy(update={"model": wanted})


def _format_errors(error: ValidationError) -> str:
    parts = []
    for item in error.errors():
        where = ".".join(str(p) for p in item["loc"]) or "(top level)"
        parts.append(f"{where}: {item['msg']} (got {item.get('input')!r})")
    return "; ".join(parts)


def parse_scene(text: str, source: str = "<scene>") -> Scene:
    """Validate a scene given as TOML text; ``source`` names it in error messages."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"scene file {source} is not valid TOML: {exc}; fix the syntax") from exc
    return scene_from_mapping(data, source)


def scene_from_mapping(data: dict[str, Any], source: str = "<scene>") -> Scene:
    """Validate a scene given as tables (a TOML file read, or JSON); ``source`` names it in
    error messages."""
    try:
        return Scene.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"scene file {source} is invalid: {_format_errors(exc)}") from exc


def load_scene(path: str | Path | None = None) -> Scene:
    """Read and validate a scene file; ``None`` loads the packaged default scene."""
    if path is None:
        text = resources.files("fakes.scenes").joinpath("default.toml").read_text(encoding="utf-8")
        return parse_scene(text, "fakes/scenes/default.toml")
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read scene file {path}: {exc.strerror}; check the path") from exc
    return parse_scene(text, str(path))
