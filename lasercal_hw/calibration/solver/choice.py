"""Which parameters besides the pose a solve estimates (``_extras``): the range error curve's terms, and
the rod axis when asked for or, with ``auto``, when the waypoints pin down its offset."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from lasercal_hw.calibration.solver.axis import _axis_advice, _axis_crb_std, _mean_crossing_along_m
from lasercal_hw.calibration.solver.data import _Data
from lasercal_hw.calibration.solver.extras import _extended_fisher, _Extras
from lasercal_hw.calibration.solver.observability import _require_observable
from lasercal_hw.calibration.solver.options import SolverOptions
from lasercal_hw.calibration.solver.range_curve import _range_terms_wanted
from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import FloatArray


def _extras(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    usable: np.ndarray,
    opts: SolverOptions,
    noise_scale: float = 1.0,
) -> _Extras:
    """Which extra parameters to estimate: refuses a requested one the waypoints cannot
    determine; with ``estimate_axis="auto"`` leaves the axis out (with a note) unless the
    Cramér-Rao bound at the start pins down its offset where the rod crosses the plane. A
    tilt the crossings cannot see (they keep to a short stretch of the rod) is estimated
    with a note: it then hardly moves the line where the waypoints measure it."""
    wanted_axis = opts.estimate_axis is True or opts.estimate_axis == "auto"
    if opts.formulation == "paper" and (opts.estimate_axis is True or opts.estimate_range_offset is True):
        raise ConfigError("the paper formulation cannot estimate the rod axis or the range offset; use ours")
    if opts.formulation == "paper":
        return _Extras()
    terms, offset_note = _range_terms_wanted(rotation, translation, data, usable, opts, noise_scale)
    if not wanted_axis:
        return _Extras(range_terms=terms, offset_note=offset_note)
    extras = _Extras(axis=True, range_terms=terms, offset_note=offset_note)
    fisher = _extended_fisher(rotation, translation, data, usable, opts, extras)
    along_m = _mean_crossing_along_m(rotation, translation, data, usable)
    offset_std_m, tilt_std_deg = _axis_crb_std(fisher, along_m)
    if opts.estimate_axis is True:
        _require_observable(fisher, opts, extras)
    elif not offset_std_m.max() <= opts.auto_axis_max_offset_std_m:
        note = (
            f"rod axis not estimated (auto): the Cramér-Rao std of its offset where it crosses the scan "
            f"plane would be {offset_std_m.max() * 1e3:.2g} mm (limit "
            f"{opts.auto_axis_max_offset_std_m * 1e3:g} mm); {_axis_advice(offset_std_m, tilt_std_deg, opts)}"
        )
        return replace(extras, axis=False, axis_note=note)
    if tilt_std_deg.max() <= opts.weak_axis_tilt_std_deg:
        return extras
    note = (
        f"rod axis tilt weakly determined by the waypoints (Cramér-Rao std {tilt_std_deg.max():.2g} deg), so "
        f"held to the given direction ({opts.axis_prior_std_deg:g} deg std): the crossings keep to a short "
        f"stretch of the rod, where its offset is what the pose relies on; "
        f"{_axis_advice(np.zeros(2), tilt_std_deg, opts)}"
    )
    return replace(extras, axis_note=note)
