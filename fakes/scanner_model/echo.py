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

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.models import FloatArray

_FWHM_TO_SIGMA = 1.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))
_MEAN_SHIFT_STEPS = 30
_TOLERANCE_M = 2e-5
_MAX_LOBES = 4
_SIMPLE_SPREAD_SIGMAS = 0.125


def detect_echo(
    t_m: FloatArray, power: FloatArray, pulse_fwhm_m: float, threshold: float, choice: str = "strongest"
) -> tuple[FloatArray, FloatArray]:
    """Range (inf: nothing detected) and peak power of the chosen lobe per beam.

    ``t_m`` and ``power`` are (beams, K): each sub-ray's range (inf: miss) and weighted
    returned power; ``threshold`` is the smallest detectable peak power; ``choice`` is
    ``strongest`` or ``first``.
    """
    sigma = pulse_fwhm_m * _FWHM_TO_SIGMA
    hit = np.isfinite(t_m) & (power > 0.0)
    p = np.where(hit, power, 0.0)
    t = np.where(hit, t_m, 0.0)
    total = p.sum(axis=1)
    t_min = np.where(hit, t_m, np.inf).min(axis=1)
    t_max = np.where(hit, t_m, -np.inf).max(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (p * t).sum(axis=1) / total
    ranges = np.where(total >= threshold, mean, np.inf)
    peaks = np.where(total >= threshold, total, 0.0)
    complex_rows = np.flatnonzero(hit.any(axis=1) & (t_max - t_min > _SIMPLE_SPREAD_SIGMAS * sigma))
    if complex_rows.size:
        r, a = _chosen_lobe(t[complex_rows], p[complex_rows], hit[complex_rows], sigma, threshold, choice)
        ranges[complex_rows], peaks[complex_rows] = r, a
    return ranges, peaks


def _waveform(x: FloatArray, t: FloatArray, p: FloatArray, sigma: float) -> FloatArray:
    return (p * np.exp(-0.5 * ((x[:, None] - t) / sigma) ** 2)).sum(axis=1)


def _chosen_lobe(
    t: FloatArray, p: FloatArray, hit: NDArray[np.bool_], sigma: float, threshold: float, choice: str
) -> tuple[FloatArray, FloatArray]:
    """Mean-shift from the nearest unexplained sub-ray climbs to the next lobe's peak; the
    search then restarts beyond that lobe, until the first detectable lobe is found
    (``first``) or the first ``_MAX_LOBES`` lobes were seen (``strongest``)."""
    rows = t.shape[0]
    ranges = np.full(rows, np.inf)
    peaks = np.zeros(rows)
    start = np.where(hit, t, np.inf).min(axis=1)
    active = np.isfinite(start)
    for _ in range(min(t.shape[1], _MAX_LOBES)):
        if not active.any():
            break
        idx = np.flatnonzero(active)
        x = start[idx]
        tt, pp = t[idx], p[idx]
        for _step in range(_MEAN_SHIFT_STEPS):
            w = pp * np.exp(-0.5 * ((x[:, None] - tt) / sigma) ** 2)
            x_new = (w * tt).sum(axis=1) / np.fmax(w.sum(axis=1), 1e-300)
            done = np.abs(x_new - x) < _TOLERANCE_M
            x = x_new
            if done.all():
                break
        amplitude = _waveform(x, tt, pp, sigma)
        found = (amplitude >= threshold) & (amplitude > peaks[idx])
        ranges[idx[found]], peaks[idx[found]] = x[found], amplitude[found]
        if choice == "first":
            active[idx[found]] = False
        # Restart at the first sub-ray clearly beyond this lobe's peak.
        beyond = np.where(hit[idx] & (tt > x[:, None] + 2.0 * sigma), tt, np.inf).min(axis=1)
        start[idx] = beyond
        active[idx] = active[idx] & np.isfinite(beyond)
    return ranges, peaks
