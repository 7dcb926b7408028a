"""The PNG report renders from plain values and refuses inconsistent input."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from pydantic import ValidationError

from lasercal_hw.geometry import euler_zyx_to_matrix, invert_transform, make_transform, pose_to_matrix
from lasercal_hw.outputs.report import ReportData, _residual_scale, render_report

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _example(n: int = 18) -> ReportData:
    """Waypoints on two semicircles through the scan plane of the paper's scanner pose."""
    T_base_laser = make_transform(euler_zyx_to_matrix(*np.radians([5.0, 7.0, 3.0])), [0.30, 0.50, 0.20])
    rng = np.random.default_rng(1)
    angles = np.radians(np.arange(n) * 20.0 % 180.0)
    poses, measured, predicted = [], [], []
    for k, angle in enumerate(angles):
        radius = 0.35 if k < n // 2 else 0.55
        centre_laser = np.array([radius * np.cos(angle - np.pi / 2), radius * np.sin(angle - np.pi / 2), 0.0])
        centre_base = T_base_laser[:3, :3] @ centre_laser + T_base_laser[:3, 3]
        above = centre_base + np.array([0.0, 0.0, 0.05])
        pose = np.concatenate([above, [0.1 * k / n, np.pi - 0.2, 0.0]])
        poses.append(pose)
        tcp_in_laser = invert_transform(T_base_laser) @ pose_to_matrix(pose)
        predicted.append(tcp_in_laser[:2, 3])
        measured.append(tcp_in_laser[:2, 3] + rng.normal(0.0, 0.0005, 2))
    if n > 5:
        measured[5] = measured[5] + [0.006, -0.004]
    used = [k != 5 for k in range(n)]
    beam_angles = np.linspace(-0.75 * np.pi, 0.75 * np.pi, 1081)
    ranges = 0.65 / np.maximum(np.abs(np.cos(beam_angles)), 0.3)
    ranges[::50] = np.nan
    return ReportData(
        title="lasercal calibration (test)",
        T_base_laser=T_base_laser,
        std_translation_mm=[0.4, 0.5, 0.9],
        std_rotation_deg=[0.02, 0.05, 0.04],
        indices=list(range(n)),
        measured_uv_m=np.array(measured),
        predicted_uv_m=np.array(predicted),
        used=used,
        tcp_poses=np.array(poses),
        background_angles_rad=beam_angles,
        background_ranges_m=ranges,
        notes=["waypoint 5 rejected: residual 7.2 mm > 3 sigma"],
    )


def _png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert data[12:16] == b"IHDR"
    assert data.rstrip(b"\0").endswith(b"IEND\xaeB`\x82")
    return struct.unpack(">II", data[16:24])


def test_report_renders_a_png(tmp_path):
    path = render_report(_example(), tmp_path / "report.png")
    assert path.stat().st_size > 50_000  # a real drawing, not an empty canvas
    assert _png_size(path) == (1800, 1050)


def test_report_from_json_round_trip(tmp_path):
    """The model travels as JSON (e.g. saved next to result.json) and renders the same."""
    data = _example(6)
    again = ReportData.model_validate_json(data.model_dump_json())
    assert again == data
    assert _png_size(render_report(again, tmp_path / "r.png", dpi=50)) == (900, 525)


def test_rms_uses_only_the_observations_the_solve_used():
    data = _example()
    norms = np.linalg.norm(data.residuals_mm(), axis=1)
    expected = np.sqrt(np.mean(np.delete(norms, 5) ** 2))
    assert data.rms_residual_mm() == pytest.approx(expected)
    assert norms[5] > 5.0


def test_inconsistent_lengths_are_refused():
    fields = _example(4).model_dump()
    fields["used"] = [True] * 3
    with pytest.raises(ValidationError, match="used has 3 entries"):
        ReportData(**fields)


@pytest.mark.parametrize(("max_residual_m", "extent_m", "expected"),
                         [(0.001, 1.0, 100), (0.0004, 1.0, 200), (0.5, 1.0, 1), (0.0, 1.0, 1),
                          (0.003, 0.5, 10)])
def test_residual_magnification_is_a_round_number(max_residual_m, extent_m, expected):
    assert _residual_scale(max_residual_m, extent_m) == expected


def test_a_dry_runs_report_says_how_far_it_is_from_the_truth() -> None:
    import matplotlib.pyplot as plt

    from lasercal_hw.outputs.report import _draw_summary

    def summary(data: ReportData) -> str:
        figure, ax = plt.subplots()
        try:
            _draw_summary(ax, data)
            return "\n".join(text.get_text() for text in ax.texts)
        finally:
            plt.close(figure)

    live = _example()
    assert "truth" not in summary(live)
    dry = live.model_copy(update={"truth_error_mm_deg": (1.5, 0.083)})
    assert "dry run, off the fake's truth: 1.50 mm, 0.083 deg" in summary(dry)
