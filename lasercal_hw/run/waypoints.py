"""The waypoints of a job: a named preset (``trajectories.presets``) with optional
parameter overrides, or a waypoint file (``trajectories.waypoint_file``: CSV or TOML)."""

from __future__ import annotations

import numpy as np

from lasercal_hw.config import JobConfig
from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import matrix_to_pose
from lasercal_hw.models import FloatArray
from trajectories.presets import get_preset
from trajectories.semicircles import parse_semicircle_parameters, semicircle_waypoints
from trajectories.waypoint import Waypoint, waypoint_matrices
from trajectories.waypoint_file import load_waypoints


def job_waypoint_list(job: JobConfig) -> list[Waypoint]:
    """The waypoints the job visits, in order, with their labels.

    ``trajectory.parameters`` override the preset's semicircle parameters field by field;
    the preset's plane-crossing check uses the job's rod.
    """
    trajectory = job.trajectory
    if trajectory.waypoints_file is not None:
        return load_waypoints(trajectory.waypoints_file)
    assert trajectory.preset is not None
    preset = get_preset(trajectory.preset)
    parameters = parse_semicircle_parameters(
        preset.parameters.model_dump() | trajectory.parameters, source=f"trajectory preset {preset.name!r}"
    )
    return semicircle_waypoints(parameters, job.rod.rod_line())


def without_spin(job: JobConfig) -> JobConfig:
    """``job`` visiting its waypoints as listed, without a twist drill's spin before them
    (``trajectory.flute_phase_deg``)."""
    return job.model_copy(update={"trajectory": job.trajectory.model_copy(update={"flute_phase_deg": None})})


def listed_waypoints(job: JobConfig) -> FloatArray:
    """The job's own waypoints (its file or preset) as UR pose vectors, as listed: without an
    adaptive design or a twist drill's spin and turn (``job_waypoints`` gives what a run visits first)."""
    return matrix_to_pose(waypoint_matrices(job_waypoint_list(job)))


class ScannerPoseMissingError(ConfigError):
    """A live run's job says nothing about where the scanner is (``require_scanner_pose``)."""


def require_scanner_pose(job: JobConfig) -> None:
    """Refuse a live run whose job says nothing about where the scanner is: a preset is laid
    out for one scanner placement (the fake cell's default scene), not for this cell."""
    if job.trajectory.waypoints_file is not None or job.scanner.nominal is not None:
        return
    raise ScannerPoseMissingError(
        f"the job gives no scanner pose, and the preset {job.trajectory.preset!r} is laid out for the "
        "fake cell's default scene (scanner at 0.30, 0.50, 0.20 m), not for your cell: measure the "
        "scanner's pose roughly and run `lasercal trajectory design --scanner-pose X Y Z YAW PITCH ROLL "
        "--config JOB --out waypoints.csv`, then put in the job the waypoints_file line its output ends "
        "with (the path as the job file reads it) and the same pose as [scanner.nominal] (or "
        "[scanner.nominal] alone to keep a preset checked for your cell)"
    )


def job_waypoints(job: JobConfig, *, live: bool = False) -> FloatArray:
    """The job's waypoints as UR pose vectors (N, 6); ``live``: for a run on a real cell,
    which needs the job to say where the scanner is (``require_scanner_pose``). An adaptive
    job's are those of its first design (``lasercal_hw.run.adaptive``), a ``flute_phase_deg`` job's
    its spin (``lasercal_hw.run.flute_spin``): the rest follows from what they measure."""
    if job.trajectory.adaptive:  # the first design; the rest follows from its estimate
        from lasercal_hw.run.adaptive import first_design

        return matrix_to_pose(waypoint_matrices(first_design(job).waypoints))
    if live:
        require_scanner_pose(job)
    if job.trajectory.flute_phase_deg is not None:  # the spin; the rest turned to the phase it tells
        from lasercal_hw.run.flute_spin import job_spin

        return job_spin(job)
    return listed_waypoints(job)


def planned_waypoints(job: JobConfig, *, live: bool = False) -> FloatArray:
    """Every waypoint a run of ``job`` plans to visit, as far as known before it moves (what a
    count, a bound or a picture of the run takes): a spun job's spin, then its waypoints as listed
    (the spin turns them about the bit, which keeps each crossing where it is); else
    ``job_waypoints``."""
    first = job_waypoints(job, live=live)
    if job.trajectory.flute_phase_deg is None:
        return first
    return np.vstack([first, listed_waypoints(job)])
