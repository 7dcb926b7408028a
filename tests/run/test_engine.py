"""The engine from Python: what it refuses before connecting. (Its dry run against the CLI's,
document, files and numbered events: tests/run/test_dry_run.py, which makes both runs.)"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from lasercal_hw.config import JobConfig, load_job, with_overrides
from lasercal_hw.errors import ConfigError, InterruptedRunError
from lasercal_hw.run.engine import CancelToken, RunRequest, calibrate
from lasercal_hw.session.reader import read_session

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(240)]


def _live_job() -> JobConfig:
    """A job for a live run: it says where the scanner roughly is."""
    return with_overrides(load_job(None), {"scanner.nominal": {"translation_m": [0.3, 0.5, 0.2]}})


def test_a_live_run_without_any_scanner_pose_points_to_trajectory_design(tmp_path: Path) -> None:
    out = tmp_path / "out"
    expected = r"no scanner pose.*lasercal trajectory design --scanner-pose"
    with pytest.raises(ConfigError, match=expected) as refused:
        calibrate(RunRequest(job=load_job(None), out_dir=out, robot_host="127.0.0.9"))
    assert not out.exists()
    # The design writes its file where it is run and ends with the line to put in the job, the
    # path as the job file reads it: the error sends there rather than naming a path of its own
    # (which a job file in another folder would read as another file).
    assert "the waypoints_file line its output ends with" in str(refused.value)
    assert 'waypoints_file = "waypoints.csv"' not in str(refused.value)


def test_a_cancelled_run_before_connecting_leaves_no_empty_folder(tmp_path: Path) -> None:
    cancel = CancelToken()
    cancel.cancel("test")
    out = tmp_path / "out"
    with pytest.raises(InterruptedRunError, match="test"):
        calibrate(RunRequest(job=_live_job(), out_dir=out, robot_host="127.0.0.9"), cancel=cancel)
    assert not out.exists()


def test_a_folder_holding_a_session_is_refused(tmp_path: Path) -> None:
    (tmp_path / "session.mcap").write_bytes(b"")
    with pytest.raises(ConfigError, match="already exists"):
        calibrate(RunRequest(job=_live_job(), out_dir=tmp_path, robot_host="127.0.0.9"))


def test_a_resumed_run_continues_on_what_it_was_recorded_on(tmp_path: Path) -> None:
    from lasercal_hw.run.engine import DRY_RUN_SCENE_FILE, META_DRY_RUN, META_SCENE, _as_recorded

    recording = tmp_path / "session.mcap"
    request = RunRequest(job=JobConfig(), out_dir=tmp_path, resume=recording)
    scene = "[rod]\nradius_m = 0.005\n"
    dry = _as_recorded(request, {META_DRY_RUN: True, META_SCENE: scene})
    assert dry.dry_run and dry.scene == tmp_path / DRY_RUN_SCENE_FILE
    assert dry.scene.read_text() == scene
    assert _as_recorded(request, {META_DRY_RUN: False}) == request
    with pytest.raises(ConfigError, match="recorded on hardware: a dry run cannot continue it"):
        _as_recorded(replace(request, dry_run=True), {META_DRY_RUN: False})
    with pytest.raises(ConfigError, match="dry run's recording: it continues against a new fake cell"):
        _as_recorded(replace(request, robot_host="127.0.0.9"), {META_DRY_RUN: True})


def test_a_cell_jobs_one_recording_resumes_only_as_the_job(tmp_path: Path) -> None:
    """``RunRequest.resume`` given a cell job's recording is refused, naming its folder: one
    scanner's run resumed on its own would write into the job's file as a one-scanner run."""
    from lasercal_hw.session.format import META_JOB_SCANNERS
    from lasercal_hw.session.recorder import SessionRecorder

    path = tmp_path / "session.mcap"
    with SessionRecorder(path, {META_JOB_SCANNERS: ["front", "rear"]}) as recorder:
        recorder.for_scanner("front").write_meta({"job": {}, "waypoints": []})
    with pytest.raises(ConfigError, match=rf"cell job's recording of scanners front: it is continued by "
                                          rf"resuming the job, its folder {tmp_path}, not one scanner's run"):
        calibrate(RunRequest(job=JobConfig(), out_dir=tmp_path, resume=path))
    assert read_session(path).scanner_names == ["front"]  # untouched


def test_a_verifys_recording_is_not_resumed_as_a_calibration(tmp_path: Path) -> None:
    """A verify records what wrote it (meta ``procedure``): resuming its recording would run the
    verify's few waypoints as a calibration, so it is refused, the file untouched."""
    from lasercal_hw.run.resume import META_PROCEDURE, Procedure
    from lasercal_hw.session.recorder import SessionRecorder

    path = tmp_path / "session.mcap"
    with SessionRecorder(path, {"job": {}, "waypoints": [], META_PROCEDURE: Procedure.VERIFY.value}):
        pass
    size = path.stat().st_size
    with pytest.raises(ConfigError, match="a verify's recording, which is not resumed: start a new verify"):
        calibrate(RunRequest(job=JobConfig(), out_dir=tmp_path, resume=path))
    assert path.stat().st_size == size
