"""The real ``lasercal serve --dry-run`` process on a loopback port, driven through HTTP only:
a dry run to the end with its events and files, one job cancelled and resumed then SIGKILLed
and resumed after a restart, activate / roll back / diff. The tests of the module share one
daemon (restarted on its data folder after the SIGKILL) and run in order."""

from __future__ import annotations

import json
import socket
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from drivers.ur.dashboard import DASHBOARD_PORT
from lasercal_hw.cli.main import main
from tests.daemon_helpers import QUICK_DRY_RUN, DaemonProcess, read_sse, wait_for

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(600)]
TERMINAL = ("succeeded", "failed", "cancelled", "interrupted")
# A calibrate job on the dry-run daemon's own fake cell: one fake cell on the machine, not two.
# No report PNG there (test 1 reads one): rendering it is a good part of a short run.
QUICK_CALIBRATE = QUICK_DRY_RUN | {
    "kind": "calibrate",
    "job": QUICK_DRY_RUN["job"]
    | {
        "output": {"report": False},
        # a real (non dry-run) job names the scanner's rough pose: the fake cell's default scene
        "scanner": {"nominal": {"translation_m": [0.30, 0.50, 0.20], "euler_zyx_deg": [5.0, 7.0, 3.0]}},
    },
}


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    process = DaemonProcess(tmp_path_factory.mktemp("daemon") / "data").start()
    try:
        yield process
    finally:
        process.stop()


@dataclass(frozen=True)
class Remote:
    """What one ``lasercal remote ...`` printed and its exit code."""

    returncode: int
    stdout: str
    stderr: str


@pytest.fixture
def remote(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, daemon: DaemonProcess):
    """``lasercal remote ...`` against the daemon, in this process (token from the environment)."""
    monkeypatch.setenv("LASERCAL_TOKEN", daemon.token)

    def run(*args: str) -> Remote:
        capsys.readouterr()
        monkeypatch.setattr(sys, "argv", ["lasercal", "remote", *args, "--daemon", daemon.url])
        with pytest.raises(SystemExit) as exited:
            main()
        captured = capsys.readouterr()
        return Remote(int(exited.value.code or 0), captured.out, captured.err)

    return run


def _progressed(waypoints: int):
    return lambda job: (
        job["state"] != "failed" and (job["state"] in TERMINAL or job["progress"]["completed"] >= waypoints)
    )


def test_dry_run_to_the_end_with_every_event_and_file(daemon: DaemonProcess) -> None:
    with daemon.client() as client, daemon.client(token=False) as anonymous:
        job = client.post("/v1/jobs", json=QUICK_DRY_RUN)
        assert job.status_code == 202, job.text
        job_id = job.json()["id"]
        busy = client.post("/v1/jobs", json=QUICK_DRY_RUN)
        assert (busy.status_code, busy.json()["code"], busy.json()["detail"]["job_id"]) == (
            409,
            "job_running",
            job_id,
        )
        assert anonymous.post("/v1/jobs", json=QUICK_DRY_RUN).status_code == 401
        wrong = anonymous.post("/v1/jobs", json=QUICK_DRY_RUN, headers={"Authorization": "Bearer wrong"})
        assert wrong.status_code == 403
        assert anonymous.post(f"/v1/jobs/{job_id}/cancel").status_code == 401

        with client.stream("GET", f"/v1/jobs/{job_id}/events") as stream:
            first = read_sse(stream, stop_after=12)
        rest: list = []
        for _ in range(4):  # reconnect after the last event seen; a device stall (CI load) is resumed
            after_id = (first + rest)[-1][0]
            with client.stream(
                "GET", f"/v1/jobs/{job_id}/events", headers={"Last-Event-ID": str(after_id)}
            ) as stream:
                rest += read_sse(stream)
            last = (first + rest)[-1][2]
            if last.get("state") != "failed" or last["error"]["code"] != "device_error":
                break
            client.post(f"/v1/jobs/{job_id}/resume", json={"confirm_motion": True}).raise_for_status()
        with client.stream("GET", f"/v1/jobs/{job_id}/events?last_event_id=0") as stream:
            everything = read_sse(stream)

        # Scans are live only (no id, never stored): the replay is everything else, in order.
        assert [event for event in first + rest if event[1] != "scan"] == everything
        assert "scan" in [kind for _, kind, _ in first + rest]
        kinds = [kind for _, kind, _ in everything]
        assert {"stage", "progress", "centre", "result", "calibration"} <= set(kinds) and "scan" not in kinds
        assert (everything[0][1], everything[0][2]["state"]) == ("state", "queued")
        assert (everything[-1][1], everything[-1][2]["state"]) == ("state", "succeeded")
        states = [data["state"] for _, kind, data in everything if kind == "state"]
        assert {"queued", "preflight", "running", "solving", "succeeded"} <= set(states)
        log = daemon.log.read_text()  # the daemon's stderr: what journalctl shows
        assert f"INFO job {job_id} queued" in log and f"INFO job {job_id} succeeded" in log

        finished = client.get(f"/v1/jobs/{job_id}").json()
        # The verdict is the calibration's business (a loaded machine can fail a gate), not the daemon's.
        assert finished["state"] == "succeeded" and isinstance(finished["verdict"]["passed"], bool)
        # The last fake cell's devices, not the defaults (a resume after a stall starts a new cell).
        cell = [data for _, kind, data in everything if kind == "stage" and "scanner_url" in data][-1]
        resolved = finished["request"]["resolved_job"]
        assert resolved["robot"]["host"] == cell["robot_host"]
        assert resolved["scanner"]["url"] == cell["scanner_url"]
        assert cell["scanner_url"].startswith("scip+tcp://127.")
        document = finished["document"]
        assert document["dry_run"] is True and document["ground_truth"]["error"]["translation_mm"] < 20.0
        calibration = client.get(f"/v1/calibrations/{finished['calibration_id']}").json()
        assert (
            calibration["job_id"] == job_id and calibration["dry_run"] is True and not calibration["active"]
        )
        result = client.get(calibration["files"]["result"]).json()
        assert result["T_base_laser"] == calibration["T_base_laser"] == document["T_base_laser"]
        assert client.get(calibration["files"]["report"]).content.startswith(b"\x89PNG")
        assert client.get(calibration["files"]["session"]).content.startswith(b"\x89MCAP")


def test_cancel_then_sigkill_each_stop_the_job_and_resume_finishes_it(daemon: DaemonProcess, remote) -> None:
    """A calibrate job on the daemon's own fake cell (so the status shows its robot), stopped
    twice: cancelled (the arm stopped, the recording kept, resume needs confirmation), then,
    resumed, the daemon killed with SIGKILL mid-run: restarted on its data folder, the job is
    ``interrupted`` and stays so until resumed, and ``lasercal remote resume`` finishes it with
    every waypoint. One job for both stops: each is a partly measured recording resumed."""
    with daemon.client() as client:
        active_before = client.get("/v1/calibration").json()
        job_id = client.post("/v1/jobs", json=QUICK_CALIBRATE).json()["id"]
        wait_for(client, job_id, _progressed(2))
        assert client.get("/v1/status").json()["job"]["id"] == job_id
        running_seen = False
        deadline = time.monotonic() + 60.0
        while not running_seen and time.monotonic() < deadline:
            wait_for(client, job_id, lambda job: job["state"] == "running")
            running_seen = client.get("/v1/status").json()["robot"]["program_running"] is True
            time.sleep(0.2)
        assert running_seen, "the status never showed the control script running"
        assert client.post(f"/v1/jobs/{job_id}/cancel").status_code == 200
        cancelled = wait_for(client, job_id, lambda job: job["state"] in TERMINAL)
        assert cancelled["state"] == "cancelled" and cancelled["error"]["code"] == "cancelled"
        assert cancelled["calibration_id"] is None
        with client.stream("GET", f"/v1/jobs/{job_id}/events?last_event_id=0") as stream:
            kinds = [kind for _, kind, _ in read_sse(stream)]
        assert "cancel_requested" in kinds and "stopped" in kinds and "result" not in kinds
        assert len(client.get(f"/v1/jobs/{job_id}/files/session.mcap").content) > 1000
        assert client.get("/v1/calibration").json() == active_before
        deadline = time.monotonic() + 30.0
        while client.get("/v1/status").json()["robot"]["program_running"] and time.monotonic() < deadline:
            time.sleep(0.2)
        assert client.get("/v1/status").json()["robot"]["program_running"] is False

        assert client.post(f"/v1/jobs/{job_id}/resume", json={}).json()["code"] == "confirmation_required"
        assert client.post(f"/v1/jobs/{job_id}/resume", json={"confirm_motion": True}).status_code == 200
        done_before_kill = cancelled["progress"]["completed"] + 2
        completed = wait_for(client, job_id, _progressed(done_before_kill))["progress"]["completed"]
        assert client.get(f"/v1/jobs/{job_id}").json()["state"] not in TERMINAL, "it ended before the kill"
    daemon.kill()
    daemon.stop()  # the killed daemon's fake cell, which a crash leaves behind
    daemon.start()
    with daemon.client() as client:
        job = client.get(f"/v1/jobs/{job_id}").json()
        assert job["state"] == "interrupted" and job["error"]["code"] == "interrupted", job
        assert client.get("/v1/status").json()["job"]["id"] == job_id
        time.sleep(1.0)
        assert client.get(f"/v1/jobs/{job_id}").json()["state"] == "interrupted", "it resumed by itself"
    finished = remote("resume", job_id, "--yes", "--wait", "--json")
    done = json.loads(finished.stdout)
    with daemon.client() as client:
        if done["state"] == "failed" and done["error"]["code"] == "device_error":  # a stalled fake (CI load)
            assert finished.returncode == 3
            wait_for(client, job_id, lambda job: job["state"] == "succeeded")
        else:
            assert done["state"] == "succeeded", (done, finished.stderr[-2000:])
            assert finished.returncode == (0 if done["passed"] else 1), finished.stderr[-2000:]
            assert done["calibration_id"]
            assert done["job_id"] == job_id and len(done["T_base_laser"]) == 4
        job = client.get(f"/v1/jobs/{job_id}").json()
        assert job["progress"]["completed"] == job["progress"]["waypoint_count"] >= completed


def test_activate_roll_back_and_diff(daemon: DaemonProcess, remote) -> None:
    with daemon.client() as client:
        newer, older = (c["id"] for c in client.get("/v1/calibrations").json()["calibrations"][:2])
        for calibration_id in (older, newer, older):
            answer = client.post(
                f"/v1/calibrations/{calibration_id}/activate", json={"reason": "test", "force": True}
            )
            assert answer.status_code == 200 and answer.json()["active"] is True
        active = client.get("/v1/calibration").json()
        assert active["id"] == older and active["exports"]["static_transform_publisher_args"]
        assert [a["calibration_id"] for a in client.get("/v1/calibrations").json()["activations"][:3]] == [
            older,
            newer,
            older,
        ]
        diff = client.get(f"/v1/calibrations/{older}/diff/{newer}").json()
        assert len(diff["translation_mm"]) == 3 and diff["translation_norm_mm"] < 20.0
        assert isinstance(diff["significant"], bool)
    history = json.loads(remote("history", "--json").stdout)["calibrations"]
    assert [c["active"] for c in history if c["id"] in (older, newer)] == [False, True]
    assert remote("activate", newer, "--reason", "roll forward", "--force").returncode == 0
    assert json.loads(remote("status", "--json").stdout)["active_calibration"]["id"] == newer
    assert json.loads(remote("diff", older, newer, "--json").stdout) == diff
    unknown = remote("activate", "cal-nope")
    assert unknown.returncode == 2 and "not_found" in unknown.stderr


def test_verify_checks_the_active_calibration_and_files_it(daemon: DaemonProcess) -> None:
    """A verify job on the daemon's own fake cell checks the active calibration; the verify
    is in the history with the calibration it checked and the estimated move."""
    with daemon.client() as client:
        active = client.get("/v1/calibration").json()["id"]
        job = client.post("/v1/jobs", json={"kind": "verify", "confirm_motion": True})
        assert job.status_code == 202, job.text
        done = wait_for(client, job.json()["id"], lambda j: j["state"] in TERMINAL)
        assert done["state"] == "succeeded", done
        filed = client.get("/v1/verifies").json()["verifies"][0]
        assert (filed["id"], filed["calibration_id"]) == (done["verify_id"], active)
        assert filed["verdict"] in ("ok", "inconclusive", "degraded", "recalibrate") and filed["reason"]


def test_a_calibrate_job_without_a_scanner_pose_is_told_the_dry_run_on_a_dry_run_daemon(
    daemon: DaemonProcess,
) -> None:
    """A calibrate job on a dry-run daemon is checked as a real cell's (the preset needs the
    scanner's pose): the 422 names that and the dry run that tries the job on the fake cell."""
    with daemon.client() as client:
        answer = client.post("/v1/jobs", json={"kind": "calibrate", "confirm_motion": True})
    assert answer.status_code == 422, answer.text
    message = answer.json()["message"]
    assert "gives no scanner pose" in message and "lasercal remote calibrate --dry-run" in message


def _replace_joint(host: str, joint: int) -> str:
    """The fake controller's own dashboard command: its kinematics calibration changes."""
    with socket.create_connection((host, DASHBOARD_PORT), timeout=5.0) as sock:
        reader = sock.makefile("rb")
        reader.readline()  # banner
        sock.sendall(f"fake replace joint {joint}\n".encode())
        return reader.readline().decode().strip()


def test_a_joint_replaced_since_the_calibration_makes_verify_recalibrate_naming_the_robot(
    daemon: DaemonProcess,
) -> None:
    """Between the dry-run calibrations above and this verify, joint 3 of the daemon's fake
    robot is replaced: the verify answers recalibrate before anything moves, naming the
    robot's calibration and both checksums (the health's view of it: tests/service/test_health.py)."""
    with daemon.client() as client:
        host = client.get("/v1/status").json()["robot"]["host"]
        before = client.get("/v1/health").json()
        assert before["scanners"][0]["robot_calibration_matches"] is True, before
        old = before["robot_calibration"]["calibration"]["checksum"]
        assert _replace_joint(host, 3).startswith("Joint 3 replaced")
        job = client.post("/v1/jobs", json={"kind": "verify", "confirm_motion": True})
        done = wait_for(client, job.json()["id"], lambda j: j["state"] in TERMINAL)
        filed = client.get("/v1/verifies").json()["verifies"][0]
        assert filed["id"] == done["verify_id"] and filed["verdict"] == "recalibrate", filed
        prefix = f"the robot's kinematics calibration changed since the calibration: checksum {old} -> "
        assert filed["reason"].startswith(prefix), filed["reason"]
        assert filed["document"]["timings"]["motion_s"] == 0.0  # nothing moved
        new = filed["reason"][len(prefix):]
        assert new != old and filed["document"]["robot_calibration"]["checksum"] == new
