"""From the light a beam's footprint sends back to the one range the scanner reports.

The spot is sampled by ``K`` sub-rays with gaussian weights; each returns a pulse of
its power at its range.  The received waveform is their sum (a gaussian pulse of the
laser's width for each sub-ray); the scanner reports the peak of one lobe above the
detection threshold: the strongest (``strongest``) or the nearest (``first``).  Surfaces
closer than about the pulse length merge into one lobe whose peak lies between them,
weighted by their power: a *steady* mixed pixel.  Surfaces further apart give separate
lobes: where their strengths are close, the speckle of each scan decides, and the beam
*flips* between them from scan to scan.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.models import FloatArray

_FWHM_TO_SIGMA = 1.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))
_MEAN_SHIFT_STEPS = 30
_TOLERANCE_M = 2e-5
_MAX_LOBES = 4
_FAINT_SHARE = 0.003
_SIMPLE_SPREAD_SIGMAS = 0.125


class Echoes(NamedTuple):
    """Per beam: the reported lobe's range (inf: none detected) and peak power, and the
    peak power of the strongest other lobe (0: none), which tells how contested it is."""

    range_m: FloatArray
    peak: FloatArray
    rival: FloatArray


def detect_echo(
    t_m: FloatArray, power: FloatArray, pulse_fwhm_m: float, threshold: float, choice: str = "strongest"
) -> Echoes:
    """The chosen lobe of every beam's waveform.

    ``t_m`` and ``power`` are (beams, K): each sub-ray's range (inf: miss) and weighted
    returned power; ``threshold`` is the smallest detectable peak power; ``choice`` is
    ``strongest`` or ``first``.
    """
    sigma = pulse_fwhm_m * _FWHM_TO_SIGMA
    # Sub-rays too faint to move any peak are left out (the halo on a dim background).
    faint = power < _FAINT_SHARE * np.sum(np.where(np.isfinite(t_m), power, 0.0), axis=1, keepdims=True)
    hit = np.isfinite(t_m) & (power > 0.0) & ~faint
    p = np.where(hit, power, 0.0)
    t = np.where(hit, t_m, 0.0)
    total = p.sum(axis=1)
    t_min = np.where(hit, t_m, np.inf).min(axis=1)
    t_max = np.where(hit, t_m, -np.inf).max(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (p * t).sum(axis=1) / total
    ranges = np.where(total >= threshold, mean, np.inf)
    peaks = np.where(total >= threshold, total, 0.0)
    rival = np.zeros_like(peaks)
    complex_rows = np.flatnonzero(hit.any(axis=1) & (t_max - t_min > _SIMPLE_SPREAD_SIGMAS * sigma))
    if complex_rows.size:
        lobes = _chosen_lobe(t[complex_rows], p[complex_rows], hit[complex_rows], sigma, threshold, choice)
        ranges[complex_rows], peaks[complex_rows], rival[complex_rows] = lobes
    return Echoes(ranges, peaks, rival)


def _waveform(x: FloatArray, t: FloatArray, p: FloatArray, sigma: float) -> FloatArray:
    return (p * np.exp(-0.5 * ((x[:, None] - t) / sigma) ** 2)).sum(axis=1)


def _chosen_lobe(
    t: FloatArray, p: FloatArray, hit: NDArray[np.bool_], sigma: float, threshold: float, choice: str
) -> Echoes:
    """Mean-shift from the nearest unexplained sub-ray climbs to the next lobe's peak; the
    search then restarts beyond that lobe, until the first detectable lobe is found
    (``first``) or the first ``_MAX_LOBES`` lobes were seen (``strongest``)."""
    rows = t.shape[0]
    ranges = np.full(rows, np.inf)
    peaks = np.zeros(rows)
    rival = np.zeros(rows)
    last_x = np.full(rows, -np.inf)
    start = np.where(hit, t, np.inf).min(axis=1)
    active = np.isfinite(start)
    for _ in range(min(t.shape[1], _MAX_LOBES)):
        if not active.any():
            break
        idx = np.flatnonzero(active)
        x = x_start = start[idx]
        tt, pp = t[idx], p[idx]
        for _step in range(_MEAN_SHIFT_STEPS):
            w = pp * np.exp(-0.5 * ((x[:, None] - tt) / sigma) ** 2)
            x_new = (w * tt).sum(axis=1) / np.fmax(w.sum(axis=1), 1e-300)
            done = np.abs(x_new - x) < _TOLERANCE_M
            x = x_new
            if done.all():
                break
        amplitude = _waveform(x, tt, pp, sigma)
        new_lobe = x > last_x[idx] + sigma  # not the previous lobe climbed again
        amplitude = np.where(new_lobe, amplitude, 0.0)
        last_x[idx] = np.where(new_lobe, x, last_x[idx])
        found = (amplitude >= threshold) & (amplitude > peaks[idx])
        rival[idx] = np.fmax(rival[idx], np.where(found, peaks[idx], amplitude))
        ranges[idx[found]], peaks[idx[found]] = x[found], amplitude[found]
        if choice == "first":
            active[idx[found]] = False
        # Restart at the first sub-ray clearly beyond this lobe's peak (or beyond this start
        # when it climbed back to the previous lobe).
        anchor = np.where(new_lobe, x + 2.0 * sigma, x_start)
        beyond = np.where(hit[idx] & (tt > anchor[:, None]), tt, np.inf).min(axis=1)
        start[idx] = beyond
        active[idx] = active[idx] & np.isfinite(beyond)
    return Echoes(ranges, peaks, rival)
