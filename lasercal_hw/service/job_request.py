"""A request to start or resume a job (the body of ``POST /v1/jobs`` and of
``POST /v1/jobs/{id}/resume``) and how it becomes the job to run."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool

from lasercal_hw.config import SCANNER_NAME_PATTERN, JobConfig, job_from_mapping, load_job, with_overrides
from lasercal_hw.errors import ConfigError
from lasercal_hw.run.waypoints import ScannerPoseMissingError, planned_waypoints
from lasercal_hw.service.errors import ConfirmationRequiredError, InvalidRequestError
from trajectories.presets import get_preset
from trajectories.semicircles import parse_semicircle_parameters

if TYPE_CHECKING:
    from drivers.access import DeviceAccess
    from lasercal_hw.service.store import HistoryStore

MOTION_KINDS = ("calibrate", "verify", "dry_run")
MAX_WAYPOINTS = 500
"""The most waypoints a request may ask for (the paper's runs use tens)."""
DAEMON_VERIFY_JOB = "the daemon verifies with the job recorded with the active calibration"
"""Which job a verify job runs (its waypoints, dwell and ``[verify]`` table): never the request's."""


def nothing_to_verify(scanner: str | None) -> str:
    """What a verify says when there is no active calibration (of ``scanner``) to check."""
    of = "" if scanner is None else f" for the scanner {scanner!r}"
    return f"there is no active calibration{of} to verify: run a calibration and activate it first"


def unknown_scanner(scanner: str | None, devices: DeviceAccess, store: HistoryStore) -> str | None:
    """Why ``scanner`` names no scanner of the daemon (its ``devices``) with no calibration on
    record in ``store`` either; None where it names one, or none is named. Said instead of "no
    calibration is active for it", which would send the caller to calibrate a scanner that is
    not there."""
    if scanner is None or store.calibrations(scanner):
        return None
    names = [name for name, _ in devices.scanners()]
    if scanner in names:
        return None
    return (
        f"this daemon has no scanner {scanner!r} (its scanners: {', '.join(names)}) and no calibration "
        "of one by that name; name one of them, or leave the scanner out"
    )


class JobBody(BaseModel):
    """A request to start a job (every kind moves an arm, the dry run a fake one)."""

    model_config = ConfigDict(extra="forbid")

    kind: Literal["calibrate", "verify", "dry_run"]
    confirm_motion: StrictBool = Field(False, description="must be JSON true: the arm moves")
    job: dict[str, Any] | None = Field(
        None,
        description="calibrate and dry_run only: job file (TOML) as a JSON object, merged over the "
        "daemon's default job (a verify runs the job recorded with the active calibration)",
    )
    activate_on_pass: StrictBool = Field(False, description="make the result active when it passes the gates")
    scanner: str | None = Field(
        None, pattern=SCANNER_NAME_PATTERN,
        description="verify only: the scanner of the cell whose active calibration to check "
        "(default: the newest activation's)",
    )
    restore_robot: StrictBool = Field(True, description="reload (and replay) the robot's program afterwards")
    dwell_s: float | None = Field(
        None, gt=0.0, le=60.0, description="calibrate and dry_run only: dwell per waypoint in s"
    )
    scene: dict[str, Any] | None = Field(
        None, description="dry_run only: the fake cell's scene (TOML tables as JSON)"
    )


class ResumeBody(BaseModel):
    """A request to continue a cancelled or interrupted job from its recording."""

    model_config = ConfigDict(extra="forbid")

    confirm_motion: StrictBool = False
    restore_robot: StrictBool = True


@dataclass(frozen=True)
class DeviceAddresses:
    """Where a job's robot and scanner are (None: the job's own)."""

    robot_host: str | None = None
    scanner_url: str | None = None
    #: A cell's scanners by name (daemon.toml's ``[scanners.NAME]``), for a cell job's scanners.
    scanner_urls: tuple[tuple[str, str], ...] = ()

    def applied_to(self, job: JobConfig) -> JobConfig:
        """``job`` pointed at these devices: a one-scanner job at ``scanner_url``, a cell job's
        scanners at the ``scanner_urls`` of the same names."""
        if job.scanners:
            urls = {f"scanners.{name}.url": url for name, url in self.scanner_urls if name in job.scanners}
            return with_overrides(job, {"robot.host": self.robot_host} | urls)
        return with_overrides(job, {"robot.host": self.robot_host, "scanner.url": self.scanner_url})


def require_confirmation(confirm_motion: bool) -> None:
    """ConfirmationRequiredError unless the request says the arm may move."""
    if not confirm_motion:
        raise ConfirmationRequiredError(
            'this job moves the arm: send "confirm_motion": true once the cell is clear',
            {"field": "confirm_motion"},
        )


def require_fields_of_kind(body: JobBody) -> None:
    """A field of other kinds only is InvalidRequestError naming it: ``scene`` is a dry run's,
    and a verify takes no ``job`` or ``dwell_s`` (it runs the job recorded with the calibration)."""
    if body.scene is not None and body.kind != "dry_run":
        raise InvalidRequestError("scene applies to dry_run jobs only", "scene")
    if body.kind != "verify":
        return
    for field in ("job", "dwell_s"):
        if getattr(body, field) is not None:
            raise InvalidRequestError(
                f"{field} applies to calibrate and dry_run jobs only: {DAEMON_VERIFY_JOB}; leave {field} "
                "out, or, to verify with other waypoints or dwell, calibrate again with a job that has "
                "them (lasercal remote calibrate --config FILE) or run 'lasercal verify --config FILE' "
                "on the cell",
                field,
            )


def _merged(base: dict[str, Any], update: dict[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in update.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merged(merged[key], value)
        else:
            merged[key] = value
    return merged


def _estimated_waypoints(job: JobConfig) -> int:
    """How many waypoints a preset's parameters ask for, counted before any is computed."""
    if job.trajectory.preset is None or job.trajectory.adaptive:
        return 0
    preset = get_preset(job.trajectory.preset)
    parameters = parse_semicircle_parameters(preset.parameters.model_dump() | job.trajectory.parameters)
    per_arc = abs(parameters.end_deg - parameters.start_deg) / parameters.step_deg + 1
    return int(len(parameters.radii_m) * per_arc)


def _require_readable_here(waypoints_file: Path, folders: tuple[Path, ...]) -> None:
    """A request's waypoint file must lie in one of ``folders``; nothing outside is opened,
    so the answer says nothing of such a file (not even whether it exists)."""
    resolved = waypoints_file.resolve()
    if not any(resolved.is_relative_to(folder.resolve()) for folder in folders):
        where = " or ".join(str(folder) for folder in folders)
        raise InvalidRequestError(
            f"job.trajectory.waypoints_file must be a file under {where}; copy the file there and "
            "give its full path (a relative name is not read in those folders)",
            "job.trajectory.waypoints_file",
        )


def _names_trajectory(table: Any) -> bool:
    """Whether a job (or a cell scanner's entry) as a request gives it names its waypoints."""
    trajectory = table.get("trajectory") if isinstance(table, dict) else None
    return isinstance(trajectory, dict) and bool({"preset", "waypoints_file"} & set(trajectory))


def _requested_scanners(request: dict[str, Any]) -> dict[str, Any]:
    scanners = request.get("scanners")
    return scanners if isinstance(scanners, dict) else {}


def _require_used_trajectory(default: JobConfig, request: dict[str, Any]) -> None:
    """A request's trajectory for the whole job is refused where a cell's scanners would not
    use it: each visits its own entry's (``[scanners.NAME.trajectory]`` of the default job)."""
    if not _names_trajectory(request):
        return
    asked = _requested_scanners(request)
    own = [name for name in default.scanners_with_own_trajectory() if not _names_trajectory(asked.get(name))]
    if own:
        preset = request["trajectory"].get("preset") or "quick"
        raise InvalidRequestError(
            f"job.trajectory: this cell's scanners {', '.join(own)} visit the waypoints of their own "
            "entries ([scanners.NAME.trajectory] of the daemon's job), so a trajectory for the whole job "
            "(such as --preset) would not be used; leave it out to run theirs, or give a scanner its own "
            "as job.scanners.NAME.trajectory (lasercal remote calibrate --config FILE with "
            f'[scanners.NAME.trajectory] preset = "{preset}")',
            "job.trajectory",
        )


def _without_replaced_trajectories(base: dict[str, Any], request: dict[str, Any]) -> dict[str, Any]:
    """``base`` without the trajectories the request names (the job's, a cell scanner's): a
    request naming its waypoints replaces the default's, not merges into them."""
    base = dict(base)
    if _names_trajectory(request):
        base.pop("trajectory", None)
    scanners = {name: dict(entry) for name, entry in (base.get("scanners") or {}).items()}
    for name, entry in _requested_scanners(request).items():
        if name in scanners and _names_trajectory(entry):
            scanners[name].pop("trajectory", None)
    if scanners:
        base["scanners"] = scanners
    return base


def resolve_job(body: JobBody, default_job: Path | None, data_dir: Path) -> JobConfig:
    """The job to run: the request's job over the default job, with the dwell override (a
    trajectory the request names, the job's or a cell scanner's, replaces the default's).
    An invalid job, an unknown preset, a waypoint file outside the data folder and the
    default job's folder, more than ``MAX_WAYPOINTS`` waypoints, a live job without a
    scanner pose, or a trajectory for a whole cell job whose scanners visit their own is
    InvalidRequestError naming the field."""
    folders = (data_dir,) + ((default_job.parent,) if default_job is not None else ())
    try:
        default = load_job(default_job)
        base = default.model_dump(mode="json", exclude_none=True)
        request = body.job or {}
        _require_used_trajectory(default, request)
        data = _merged(_without_replaced_trajectories(base, request), request)
        if body.dwell_s is not None:
            data["dwell_s"] = body.dwell_s
        job = job_from_mapping(data, "job")
        count = 0
        for name in job.scanner_names():  # a cell job's scanners each visit their own waypoints
            scanner_job = job.for_scanner(name)
            if scanner_job.trajectory.waypoints_file is not None:
                _require_readable_here(scanner_job.trajectory.waypoints_file, folders)
            if (estimated := _estimated_waypoints(scanner_job)) > MAX_WAYPOINTS:
                raise InvalidRequestError(
                    f"job.trajectory.parameters ask for {estimated} waypoints; at most "
                    f"{MAX_WAYPOINTS} are taken (raise step_deg or use fewer arcs)",
                    "job.trajectory.parameters",
                )
            count += len(planned_waypoints(scanner_job, live=body.kind == "calibrate"))
    except ScannerPoseMissingError as exc:
        raise InvalidRequestError(str(exc), "job.scanner.nominal") from None
    except ConfigError as exc:
        raise InvalidRequestError(str(exc).replace("\n ", ""), "job") from None
    if count > MAX_WAYPOINTS:
        raise InvalidRequestError(
            f"the job has {count} waypoints; at most {MAX_WAYPOINTS} are taken", "job.trajectory"
        )
    return job


def scene_file_text(body: JobBody) -> str | None:
    """The dry run's scene file for the request's ``scene`` (None without one), validated
    by ``fakes.scene``: a bad scene is InvalidRequestError (a scene for another kind:
    ``require_fields_of_kind``)."""
    if body.scene is None:
        return None
    from fakes.scene import scene_from_mapping

    try:
        return scene_from_mapping(body.scene, "scene").to_toml()
    except ConfigError as exc:
        raise InvalidRequestError(str(exc).replace("\n", " "), "scene") from None
