"""The calibration history: file a finished calibration, summarise it, activate it
(rollback is activating an older one), export it and compare two; and the verifies
filed against them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from lasercal_hw.config import DEFAULT_SCANNER_NAME
from lasercal_hw.geometry import matrix_to_rotvec
from lasercal_hw.outputs.exports import scanner_frame, static_transform_publisher_args, urdf_joint
from lasercal_hw.run.outputs import RESULT_FILE, read_result_file
from lasercal_hw.service.errors import ConflictError, NotFoundError, folder_file, not_found
from lasercal_hw.service.events import EventBus
from lasercal_hw.service.store import HistoryStore, new_id, utc_now

SIGNIFICANCE_SIGMA = 3.0
"""A difference is significant when some component exceeds this many combined standard deviations."""
_SUMMARY_FIELDS = (
    "T_base_laser",
    "translation_m",
    "euler_zyx_deg",
    "std_translation_mm",
    "std_rotation_deg",
    "crb_translation_mm",
    "crb_rotation_deg",
    "rms_residual_mm",
    "range_offset",
)


class CalibrationHistory:
    """Calibrations in the store, their files on disk beside it."""

    def __init__(self, store: HistoryStore, bus: EventBus) -> None:
        self._store = store
        self._bus = bus

    def record(
        self, job_id: str | None, directory: Path, dry_run: bool, created_utc: str | None = None,
        scanner: str = DEFAULT_SCANNER_NAME,
    ) -> str:
        """File the calibration of ``scanner`` whose ``result.json`` is in ``directory`` (made
        at ``created_utc``, default now); returns its id."""
        read = read_result_file(directory / RESULT_FILE)
        calibration_id = new_id("cal")
        result = read.result.model_dump(mode="json")
        summary = {
            "id": calibration_id,
            "created_utc": created_utc or utc_now(),
            "job_id": job_id,
            "dry_run": dry_run,
            "passed": read.passed,
        } | {key: result[key] for key in _SUMMARY_FIELDS}
        summary["verdict"] = read.verdict
        summary["devices"] = {
            "robot": read.robot, "scanner": read.scanner, "robot_calibration": read.robot_calibration
        }
        self._store.add_calibration(calibration_id, job_id, dry_run, read.passed, summary, directory, scanner)
        return calibration_id

    def filed(self, job_id: str, scanner: str) -> str | None:
        """The id of the calibration of ``scanner`` the job ``job_id`` filed, or None."""
        return self._store.job_calibration_id(job_id, scanner)

    def _stored(self, calibration_id: str) -> tuple[dict[str, Any], Path]:
        found = self._store.calibration(calibration_id)
        if found is None:
            raise not_found("calibration", calibration_id)
        return found

    def _present(self, summary: dict[str, Any], directory: Path) -> dict[str, Any]:
        base = f"/v1/calibrations/{summary['id']}/files/"
        files = (
            {
                path.name.split(".")[0]: base + path.name
                for path in sorted(directory.iterdir())
                if path.is_file()
            }
            if directory.is_dir()
            else {}
        )
        active = summary["id"] == self._store.active_calibration_id(summary["scanner"])
        return summary | {"active": active, "files": files}

    def summary(self, calibration_id: str) -> dict[str, Any]:
        """One calibration summary (NotFoundError when unknown)."""
        summary, directory = self._stored(calibration_id)
        return self._present(summary, directory)

    def all(self, scanner: str | None = None) -> list[dict[str, Any]]:
        """Every summary (of ``scanner``, or of every scanner), newest first."""
        return [self._present(s, self._stored(s["id"])[1]) for s in self._store.calibrations(scanner)]

    def earlier_than(self, summary: dict[str, Any]) -> list[dict[str, Any]]:
        """The stored summaries of ``summary``'s scanner made before it and not marked bad,
        newest first (no file listing: the health figure's history)."""
        return [
            s for s in self._store.calibrations(summary["scanner"])
            if s["created_utc"] < summary["created_utc"] and not s.get("bad")
        ]

    def active_summary(self, scanner: str | None = None) -> dict[str, Any] | None:
        """The active calibration's summary (of ``scanner``; None: the newest activation of
        any scanner, a one-scanner daemon's one), or None."""
        active_id = self._store.active_calibration_id(scanner)
        return None if active_id is None else self.summary(active_id)

    def active(self, scanner: str | None = None) -> dict[str, Any]:
        """The active calibration (of ``scanner``) with its exports, whose child frame is
        ``laser`` for the scanner ``default`` and ``laser_<name>`` for a named one
        (NotFoundError when none is active)."""
        summary = self.active_summary(scanner)
        if summary is None:
            of = "" if scanner is None else f" for the scanner {scanner!r}"
            raise NotFoundError(
                f"no calibration is active{of} yet; run a calibrate job "
                "with activate_on_pass or activate one with POST /v1/calibrations/{id}/activate",
                code="no_active_calibration",
            )
        T = np.asarray(summary["T_base_laser"], dtype=float)
        child = scanner_frame(summary["scanner"])
        return summary | {
            "exports": {
                "urdf_joint": urdf_joint(T, child=child),
                "static_transform_publisher_args": static_transform_publisher_args(T, child_frame_id=child),
            }
        }

    def file(self, calibration_id: str, name: str) -> Path:
        """A file of a calibration (NotFoundError when there is no such file)."""
        _, directory = self._stored(calibration_id)
        return folder_file(
            directory,
            name,
            f"calibration {calibration_id} has no file {name!r}; its files "
            f"are listed in GET /v1/calibrations/{calibration_id}",
        )

    def activate(self, calibration_id: str, reason: str, *, force: bool = False) -> dict[str, Any]:
        """Make a calibration the active one (recorded in the activation log). One that failed
        its quality gates needs ``force``."""
        summary, _ = self._stored(calibration_id)
        _refuse_if_bad(summary, "calibration_marked_bad", "a bad one is never active: activate another one")
        if not summary["passed"] and not force:
            raise ConflictError(
                f"calibration {calibration_id} failed its quality "
                'gates; send "force": true to activate it anyway',
                {"calibration_id": calibration_id},
                code="failed_quality_gates",
            )
        self._store.activate(calibration_id, reason)
        self._bus.publish(
            "activation", {"calibration_id": calibration_id, "reason": reason, "scanner": summary["scanner"]}
        )
        return self.summary(calibration_id)

    def mark_bad(self, calibration_id: str, by: str, reason: str) -> dict[str, Any]:
        """Record that ``by`` found the calibration bad and why (ConflictError when it already
        is: the first record stays). The active one is deactivated, and the event says so."""
        summary, _ = self._stored(calibration_id)
        _refuse_if_bad(summary, "already_marked_bad", "the first record stays")
        was_active = self._store.active_calibration_id(summary["scanner"]) == calibration_id
        time_utc = self._store.mark_bad(calibration_id, by, reason)
        event = {"calibration_id": calibration_id, "by": by, "reason": reason, "time_utc": time_utc,
                 "deactivated": was_active}
        self._bus.publish("calibration_marked_bad", event)
        if was_active:
            self._bus.publish(
                "deactivation",
                {"calibration_id": calibration_id, "reason": f"marked bad by {by}: {reason}"},
            )
        return self.summary(calibration_id)

    def latest_verify(self, calibration_id: str) -> dict[str, Any] | None:
        """The newest verify of one calibration, or None."""
        return next((v for v in self._store.verifies() if v.get("calibration_id") == calibration_id), None)

    def activations(self) -> list[dict[str, Any]]:
        """The activation log, newest first."""
        return self._store.activations()

    def record_verify(self, job_id: str, summary: dict[str, Any]) -> str:
        """File a verify of a calibration; returns its id."""
        verify_id = new_id("verify")
        self._store.add_verify(verify_id, job_id, summary | {"id": verify_id})
        return verify_id

    def verifies(self) -> list[dict[str, Any]]:
        """Every verify, newest first."""
        return self._store.verifies()

    def diff(self, a: str, b: str) -> dict[str, Any]:
        """The change from ``a`` to ``b`` in mm and degrees, and whether it is significant."""
        first, _ = self._stored(a)
        second, _ = self._stored(b)
        if first["scanner"] != second["scanner"]:
            raise ConflictError(
                f"calibration {a} is of the scanner {first['scanner']!r} and {b} of {second['scanner']!r}: "
                "compare two calibrations of one scanner (the scanner-to-scanner transform is in the cell "
                "job's cell.json)",
                {"from": a, "to": b},
                code="different_scanners",
            )
        return transform_change(first, second)


def _refuse_if_bad(summary: dict[str, Any], code: str, consequence: str) -> None:
    """ConflictError ``code`` naming who marked the calibration bad, when and why."""
    bad = summary["bad"]
    if bad is not None:
        raise ConflictError(
            f"calibration {summary['id']} was marked bad by {bad['by']} at {bad['time_utc']} "
            f"({bad['reason']}); {consequence}",
            {"calibration_id": summary["id"], "bad": bad},
            code=code,
        )


def transform_change(first: dict[str, Any], second: dict[str, Any]) -> dict[str, Any]:
    """Translation (mm, base frame) and rotation (deg, rotation vector about the base axes,
    ``R_b R_a^T``) from ``first`` to ``second``, against their combined standard deviations."""
    Ta, Tb = np.asarray(first["T_base_laser"], dtype=float), np.asarray(second["T_base_laser"], dtype=float)
    translation_mm = 1000.0 * (Tb[:3, 3] - Ta[:3, 3])
    rotation_deg = np.degrees(matrix_to_rotvec(Tb[:3, :3] @ Ta[:3, :3].T))
    std_t = np.hypot(first["std_translation_mm"], second["std_translation_mm"])
    std_r = np.hypot(first["std_rotation_deg"], second["std_rotation_deg"])
    significant = bool(
        np.any(np.abs(translation_mm) > SIGNIFICANCE_SIGMA * std_t)
        or np.any(np.abs(rotation_deg) > SIGNIFICANCE_SIGMA * std_r)
    )
    return {
        "from": first["id"],
        "to": second["id"],
        "translation_mm": translation_mm.tolist(),
        "translation_norm_mm": float(np.linalg.norm(translation_mm)),
        "rotation_deg": rotation_deg.tolist(),
        "rotation_angle_deg": float(np.linalg.norm(rotation_deg)),
        "combined_std_translation_mm": std_t.tolist(),
        "combined_std_rotation_deg": std_r.tolist(),
        "significance_sigma": SIGNIFICANCE_SIGMA,
        "significant": significant,
    }
