"""A one-page PNG report of a calibration: the scan plane with measured and predicted rod
centres, residuals per waypoint, the trajectory, and the transform with its uncertainty.

The sequencer (live run) and ``lasercal solve`` (replay) both fill a ``ReportData`` from
their plain values and call ``render_report``. Matplotlib is used through its object API
with the Agg canvas: no pyplot state, no display needed, safe in threads. It is imported when
a report is drawn, not with this module (0.3 s that a run's start or ``--help`` need not wait).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import matrix_to_euler_zyx, matrix_to_quat
from lasercal_hw.models import FloatArray

if TYPE_CHECKING:
    from matplotlib.axes import Axes

_USED_COLOUR = "tab:blue"
_PREDICTED_COLOUR = "tab:orange"
_OUTLIER_COLOUR = "tab:red"
_SCALE_STEPS = (1, 2, 5)


class ReportData(BaseModel):
    """What the report shows; one entry per observation in ``indices`` order.

    Centres are (u, v) in the scan plane in metres; ``predicted_uv_m`` comes from the solved
    transform (the solver's measurement model). Arrays may be given as numpy arrays.
    """

    model_config = ConfigDict(frozen=True)

    title: str = "lasercal calibration"
    T_base_laser: list[list[float]] = Field(description="4x4 pose of the scanner in the base frame")
    std_translation_mm: list[float] | None = Field(None, description="x, y, z")
    std_rotation_deg: list[float] | None = Field(None, description="as CalibrationResult.std_rotation_deg")
    indices: list[int]
    measured_uv_m: list[list[float]]
    predicted_uv_m: list[list[float]]
    used: list[bool]
    tcp_poses: list[list[float]] = Field(description="UR pose vector of each observation, base frame")
    background_angles_rad: list[float] = Field(default_factory=list)
    background_ranges_m: list[float | None] = Field(default_factory=list, description="NaN/None: no return")
    fov_min_rad: float = -0.75 * math.pi
    fov_max_rad: float = 0.75 * math.pi
    notes: list[str] = Field(default_factory=list)
    truth_error_mm_deg: tuple[float, float] | None = Field(
        None, description="a dry run: translation (mm) and rotation (deg) off the fake cell's ground truth"
    )

    @model_validator(mode="before")
    @classmethod
    def _arrays_to_lists(cls, values: Any) -> Any:
        if not isinstance(values, dict):
            return values
        values = {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in values.items()}
        ranges = values.get("background_ranges_m")
        if ranges is not None:  # NaN -> None: equal to itself and valid JSON
            values["background_ranges_m"] = [
                None if r is None or not math.isfinite(r) else r for r in ranges
            ]
        return values

    @model_validator(mode="after")
    def _consistent(self) -> ReportData:
        if np.asarray(self.T_base_laser).shape != (4, 4):
            raise ValueError("T_base_laser must be 4x4")
        count = len(self.indices)
        for name in ("measured_uv_m", "predicted_uv_m", "used", "tcp_poses"):
            if len(getattr(self, name)) != count:
                raise ValueError(f"{name} has {len(getattr(self, name))} entries, indices has {count}")
        for name, width in (("measured_uv_m", 2), ("predicted_uv_m", 2), ("tcp_poses", 6)):
            if any(len(row) != width for row in getattr(self, name)):
                raise ValueError(f"every row of {name} must have {width} values")
        if len(self.background_angles_rad) != len(self.background_ranges_m):
            raise ValueError("background_angles_rad and background_ranges_m differ in length")
        return self

    def residuals_mm(self) -> FloatArray:
        """Measured minus predicted centre, (N, 2) in millimetres."""
        return (np.asarray(self.measured_uv_m, dtype=float).reshape(-1, 2)
                - np.asarray(self.predicted_uv_m, dtype=float).reshape(-1, 2)) * 1000.0

    def rms_residual_mm(self) -> float:
        """Root mean square residual norm over the observations used by the solve."""
        norms = np.linalg.norm(self.residuals_mm(), axis=1)[np.asarray(self.used, dtype=bool)]
        return float(np.sqrt(np.mean(norms**2))) if norms.size else float("nan")


def render_report(data: ReportData, path: str | Path, *, dpi: int = 100) -> Path:
    """Draw the report and write it as a PNG file; returns the path."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = Path(path)
    figure = Figure(figsize=(18, 10.5), layout="constrained")
    grid = figure.add_gridspec(2, 3, width_ratios=[1.25, 1.0, 0.85])
    _draw_scan_plane(figure.add_subplot(grid[0, 0]), data)
    _draw_residuals(figure.add_subplot(grid[0, 1]), data)
    _draw_trajectory(figure.add_subplot(grid[1, 0]), data, (0, 1), "top view (x, y)")
    _draw_trajectory(figure.add_subplot(grid[1, 1]), data, (0, 2), "side view (x, z)")
    _draw_summary(figure.add_subplot(grid[:, 2]), data)
    figure.suptitle(data.title, fontsize=15)
    FigureCanvasAgg(figure)
    try:
        figure.savefig(path, dpi=dpi, format="png")
    except OSError as exc:
        raise ConfigError(f"cannot write report {path}: {exc.strerror or exc}") from exc
    return path


def _residual_scale(max_residual_m: float, extent_m: float) -> int:
    """A round magnification (1, 2, 5, 10, 20, ...) drawing the largest residual (of the
    observations used; outliers may run longer) at about a tenth of the plot."""
    if max_residual_m <= 0.0:
        return 1
    wanted = 0.1 * extent_m / max_residual_m
    decade = 10 ** math.floor(math.log10(max(wanted, 1.0)))
    return max(step * decade for step in _SCALE_STEPS if step * decade <= max(wanted, 1.0))


def _draw_scan_plane(ax: Axes, data: ReportData) -> None:
    from matplotlib.patches import Wedge

    measured = np.asarray(data.measured_uv_m, dtype=float).reshape(-1, 2)
    predicted = np.asarray(data.predicted_uv_m, dtype=float).reshape(-1, 2)
    used = np.asarray(data.used, dtype=bool)
    centres = np.vstack([measured, predicted, np.zeros((1, 2))])
    extent_m = max(0.5, 1.3 * float(np.max(np.abs(centres))))
    ax.add_patch(Wedge((0.0, 0.0), 2.0 * extent_m, math.degrees(data.fov_min_rad),
                       math.degrees(data.fov_max_rad), color="tab:green", alpha=0.07, label="field of view"))
    if data.background_angles_rad:
        angles = np.asarray(data.background_angles_rad, dtype=float)
        ranges = np.asarray([np.nan if r is None else r for r in data.background_ranges_m], dtype=float)
        ok = np.isfinite(ranges)
        ax.scatter(ranges[ok] * np.cos(angles[ok]), ranges[ok] * np.sin(angles[ok]), s=2, color="0.55",
                   label="averaged scan")
    ax.plot([0.0, 0.15 * extent_m], [0.0, 0.0], color="black", linewidth=1.5)
    ax.plot([0.0], [0.0], marker="s", color="black", label="scanner (x axis)")
    ax.scatter(measured[used, 0], measured[used, 1], s=30, color=_USED_COLOUR, label="measured centre")
    ax.scatter(measured[~used, 0], measured[~used, 1], s=40, color=_OUTLIER_COLOUR, label="outlier")
    ax.scatter(predicted[:, 0], predicted[:, 1], s=40, marker="x", color=_PREDICTED_COLOUR,
               label="predicted centre")
    delta = measured - predicted
    norms = np.linalg.norm(delta, axis=1)
    scale = _residual_scale(float(np.max(norms[used] if used.any() else norms, initial=0.0)), extent_m)
    colours = [_USED_COLOUR if u else _OUTLIER_COLOUR for u in used]
    ax.quiver(predicted[:, 0], predicted[:, 1], scale * delta[:, 0], scale * delta[:, 1], color=colours,
              angles="xy", scale_units="xy", scale=1.0, width=0.004)
    for index, (u, v) in zip(data.indices, measured, strict=True):
        ax.annotate(str(index), (u, v), textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.text(0.02, 0.02, f"residual vectors x{scale}: 1 mm is drawn {scale} mm long",
            transform=ax.transAxes, fontsize=9, bbox={"facecolor": "white", "alpha": 0.8})
    ax.set_xlim(-extent_m, extent_m)
    ax.set_ylim(-extent_m, extent_m)
    ax.set_aspect("equal")
    ax.set_xlabel("u = x_laser [m]")
    ax.set_ylabel("v = y_laser [m]")
    ax.set_title("scan plane (scanner frame)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)


def _draw_residuals(ax: Axes, data: ReportData) -> None:
    norms = np.linalg.norm(data.residuals_mm(), axis=1)
    used = np.asarray(data.used, dtype=bool)
    positions = np.arange(len(data.indices))
    ax.bar(positions[used], norms[used], color=_USED_COLOUR, label="used")
    if not used.all():  # an empty bar series would show in the legend in the default colour
        ax.bar(positions[~used], norms[~used], color=_OUTLIER_COLOUR, hatch="//", label="outlier (not used)")
    rms = data.rms_residual_mm()
    if math.isfinite(rms):
        ax.axhline(rms, color="black", linestyle="--", linewidth=1, label=f"RMS (used) {rms:.3f} mm")
    ax.set_xticks(positions, [str(i) for i in data.indices], fontsize=7 if len(positions) > 25 else 9)
    ax.set_xlabel("waypoint index")
    ax.set_ylabel("|measured - predicted| [mm]")
    ax.set_title("residual per waypoint")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8)


def _draw_trajectory(ax: Axes, data: ReportData, axes: tuple[int, int], title: str) -> None:
    names = "xyz"
    positions = np.asarray(data.tcp_poses, dtype=float).reshape(-1, 6)[:, :3]
    used = np.asarray(data.used, dtype=bool)
    transform = np.asarray(data.T_base_laser, dtype=float)
    a, b = axes
    ax.plot(positions[:, a], positions[:, b], color="0.6", linewidth=1, zorder=1)
    ax.scatter(positions[used, a], positions[used, b], s=25, color=_USED_COLOUR, label="TCP (used)", zorder=2)
    ax.scatter(positions[~used, a], positions[~used, b], s=35, color=_OUTLIER_COLOUR, label="TCP (outlier)",
               zorder=2)
    for index, point in zip(data.indices, positions, strict=True):
        ax.annotate(str(index), (point[a], point[b]), textcoords="offset points", xytext=(3, 3), fontsize=7)
    origin = transform[:3, 3]
    arrow = 0.1 * transform[:3, 0]
    ax.plot([origin[a]], [origin[b]], marker="^", markersize=10, color="tab:green", label="scanner")
    ax.annotate("", (origin[a] + arrow[a], origin[b] + arrow[b]), (origin[a], origin[b]),
                arrowprops={"arrowstyle": "->", "color": "tab:green"})
    ax.plot([0.0], [0.0], marker="+", markersize=12, color="black", label="robot base")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"{names[a]}_base [m]")
    ax.set_ylabel(f"{names[b]}_base [m]")
    ax.set_title(f"trajectory, {title}")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)


def _vector(values: Any, digits: int) -> str:
    return "(" + ", ".join(f"{v:.{digits}f}" for v in values) + ")"


def _draw_summary(ax: Axes, data: ReportData) -> None:
    transform = np.asarray(data.T_base_laser, dtype=float)
    yaw, pitch, roll = np.degrees(matrix_to_euler_zyx(transform[:3, :3]))
    used = np.asarray(data.used, dtype=bool)
    outliers = [str(i) for i, u in zip(data.indices, data.used, strict=True) if not u]
    lines = [
        "T_base_laser (scanner in robot base)",
        "",
        f"translation [mm]  {_vector(transform[:3, 3] * 1000.0, 2)}",
        f"yaw/pitch/roll [deg]  {_vector([yaw, pitch, roll], 4)}",
        "  (R = Rz(yaw) Ry(pitch) Rx(roll))",
        f"quaternion xyzw  {_vector(matrix_to_quat(transform[:3, :3]), 6)}",
        "",
        "matrix:",
        *(f"  {_vector(row, 6)}" for row in transform),
        "",
    ]
    if data.std_translation_mm is not None:
        lines.append(f"std translation [mm]  {_vector(data.std_translation_mm, 3)}")
    if data.std_rotation_deg is not None:
        lines.append(f"std rotation [deg]  {_vector(data.std_rotation_deg, 4)}")
    lines += [
        "",
        f"waypoints: {len(data.indices)}, used {int(used.sum())}, outliers {len(outliers)}",
        f"outlier waypoints: {', '.join(outliers) if outliers else 'none'}",
        f"RMS residual (used): {data.rms_residual_mm():.3f} mm",
    ]
    if data.truth_error_mm_deg is not None:
        translation_mm, rotation_deg = data.truth_error_mm_deg
        lines.append(f"dry run, off the fake's truth: {translation_mm:.2f} mm, {rotation_deg:.3f} deg")
    if data.notes:
        lines += ["", "notes:", *(f"- {note}" for note in data.notes)]
    ax.axis("off")
    ax.text(0.0, 1.0, "\n".join(lines), transform=ax.transAxes, va="top", ha="left", family="monospace",
            fontsize=9.5, wrap=True)
