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


def _chosen_lobe(
    t: FloatArray, p: FloatArray, hit: NDArray[np.bool_], sigma: float, threshold: float, choice: str
) -> Echoes:
    """Every lobe at once: the waveform sampled at the sub-rays' own ranges and halfway
    between them has one local maximum per lobe; each is refined by mean shift (the fixed
    point of a gaussian mixture's peak), then the strongest (``strongest``) or nearest
    (``first``) detectable one is chosen and the strongest of the others is its rival."""
    rows, k = t.shape
    order = np.argsort(np.where(hit, t, np.inf), axis=1)
    tt = np.take_along_axis(np.where(hit, t, np.inf), order, axis=1)
    pp = np.take_along_axis(np.where(hit, p, 0.0), order, axis=1)
    samples = np.full((rows, 2 * k - 1), np.inf)
    samples[:, 0::2] = tt
    samples[:, 1::2] = 0.5 * (tt[:, :-1] + tt[:, 1:])
    valid = np.isfinite(samples)
    finite_tt = np.where(np.isfinite(tt), tt, 0.0)
    at = np.where(valid, samples, 0.0)
    gap = (at[:, :, None] - finite_tt[:, None, :]) / sigma
    wave = (pp[:, None, :] * np.exp(-0.5 * gap**2)).sum(axis=2)
    wave = np.where(valid, wave, -np.inf)
    before = np.concatenate([np.full((rows, 1), -np.inf), wave[:, :-1]], axis=1)
    after = np.concatenate([wave[:, 1:], np.full((rows, 1), -np.inf)], axis=1)
    peak_row, peak_col = np.nonzero(valid & (wave >= before) & (wave > after))
    x = samples[peak_row, peak_col]
    tp, ppp = finite_tt[peak_row], pp[peak_row]
    moving = np.arange(x.size)
    for _step in range(_MEAN_SHIFT_STEPS):
        w = ppp[moving] * np.exp(-0.5 * ((x[moving, None] - tp[moving]) / sigma) ** 2)
        x_new = (w * tp[moving]).sum(axis=1) / np.fmax(w.sum(axis=1), 1e-300)
        still = np.abs(x_new - x[moving]) >= _TOLERANCE_M
        x[moving] = x_new
        moving = moving[still]
        if not moving.size:
            break
    amplitude = (ppp * np.exp(-0.5 * ((x[:, None] - tp) / sigma) ** 2)).sum(axis=1)
    lobe_x = np.full((rows, 2 * k - 1), np.inf)
    lobe_a = np.zeros((rows, 2 * k - 1))
    lobe_x[peak_row, peak_col], lobe_a[peak_row, peak_col] = x, amplitude
    detectable = lobe_a >= threshold
    if choice == "first":
        pick = np.argmax(detectable, axis=1)  # samples, and so lobes, are in range order
    else:
        pick = np.argmax(np.where(detectable, lobe_a, -1.0), axis=1)
    every = np.arange(rows)
    found = detectable[every, pick]
    with np.errstate(invalid="ignore"):  # inf - inf where a row has no lobe
        same_lobe = np.abs(lobe_x - lobe_x[every, pick][:, None]) < 0.25 * sigma  # maxima met at one peak
    rival = np.where(same_lobe, 0.0, lobe_a).max(axis=1)
    ranges = np.where(found, lobe_x[every, pick], np.inf)
    return Echoes(ranges, np.where(found, lobe_a[every, pick], 0.0), np.where(found, rival, 0.0))
