"""The intensity channel: the centre across the bearing from the middle of the rod's echo, and a
polished rod on few beams placed along it by its glint."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction.beams import _range_sigma
from lasercal_hw.scan.extraction.results import RodCentre
from lasercal_hw.scan.extraction.section import _across_bearing, _Section
from lasercal_hw.scan.extraction.settings import ExtractionSettings
from lasercal_hw.scan.extraction.spot import _spot_parts, _spot_sigma_m

#: The fewest of ``echo_middle_levels`` whose middle must be read on the rod's beams (a far rod's
#: lobe, wider than the rod, does not fall to the lowest levels on them).
MIN_ECHO_MIDDLE_LEVELS = 2


@dataclass(frozen=True)
class EchoMiddle:
    """The middle of a rod's echo strength across the bearing, seen from a centre."""

    #: The middle's bearing (rad, the scan's angles).
    bearing_rad: float
    #: How far across the centre's bearing the middle lies (m, at the centre's range; positive
    #: counterclockwise).
    shift_m: float
    #: The levels' scatter of ``shift_m``, and the mean's (m^2): a plain rod's covariance takes it,
    #: a twist drill's verify its dwell noise (a plain rod's is ``intensity_noise_m2``).
    noise_m2: float
    #: The beam step at the centre's range (m): where a flat-topped lobe's middle can lie.
    step_m: float
    #: What the noise of the averaged intensities moves ``shift_m`` by (m^2: each crossing's
    #: interpolation and level, through the beams it reads); None where the scan gives no
    #: intensity std.
    intensity_noise_m2: float | None = None

    def turned_onto(self, centre_uv_m: FloatArray) -> FloatArray:
        """``centre_uv_m`` turned about the scanner onto the middle's bearing (its range kept)."""
        direction = np.array([np.cos(self.bearing_rad), np.sin(self.bearing_rad)])
        return float(np.linalg.norm(centre_uv_m)) * direction

    def noise_uv_m2(self, centre_uv_m: FloatArray) -> FloatArray:
        """``noise_m2`` across the bearing of ``centre_uv_m`` (2x2, m^2)."""
        across = _across_bearing(centre_uv_m)
        return self.noise_m2 * np.outer(across, across)


def echo_middle(
    scan: AveragedScan, centre_uv_m: FloatArray, semi_major_m: float, levels: tuple[float, ...]
) -> EchoMiddle | None:
    """The middle of the rod's echo strength across the bearing of ``centre_uv_m``: at each of
    ``levels`` of the brightest beam on the rod (within ``semi_major_m`` of the centre's
    bearing, nearer than it), the middle of where the intensity falls through that level on
    either side (interpolated between beams that read the rod), averaged over the levels.
    None without intensities, or where fewer than ``MIN_ECHO_MIDDLE_LEVELS`` are crossed on the
    rod's beams on both sides (the background's echo won there)."""
    if scan.intensities is None or not levels:
        return None
    intensities, ranges = scan.intensities, scan.ranges_m
    distance_m = float(np.linalg.norm(centre_uv_m))
    bearing_rad = float(np.arctan2(centre_uv_m[1], centre_uv_m[0]))
    half_rad = float(np.arcsin(min(semi_major_m / distance_m, 1.0)))
    within = np.abs(scan.angles_rad - bearing_rad) <= half_rad
    on_rod = within & (ranges < distance_m) & np.isfinite(intensities)
    if not np.any(on_rod):
        return None
    brightest = int(np.flatnonzero(on_rod)[int(np.argmax(intensities[on_rod]))])
    on_rod_m = float(ranges[brightest]) + 2.0 * semi_major_m
    middles_rad = []
    # How the middles move with each beam's intensity (rad per unit), summed over the levels read.
    gradient = np.zeros(ranges.size)
    for level in levels:
        threshold = level * float(intensities[brightest])
        sides: list[float] = []
        moves = np.zeros(ranges.size)
        for direction in (-1, 1):
            i = brightest
            while 0 <= i + direction < ranges.size and ranges[i + direction] < on_rod_m and (
                intensities[i + direction] > threshold
            ):  # NaN: False
                i += direction
            j = i + direction
            if not (0 <= j < ranges.size and ranges[j] < on_rod_m and np.isfinite(intensities[j])):
                break
            drop = intensities[i] - intensities[j]
            share = (intensities[i] - threshold) / drop
            span_rad = scan.angles_rad[j] - scan.angles_rad[i]
            sides.append(scan.angles_rad[i] + share * span_rad)
            # The crossing (half of this level's middle) moves with the two beams it lies
            # between and with the level, a share of the brightest beam.
            moves[i] += 0.5 * span_rad * (threshold - intensities[j]) / drop**2
            moves[j] += 0.5 * span_rad * (intensities[i] - threshold) / drop**2
            moves[brightest] -= 0.5 * span_rad * level / drop
        if len(sides) == 2:
            middles_rad.append(0.5 * (sides[0] + sides[1]))
            gradient += moves
    if len(middles_rad) < MIN_ECHO_MIDDLE_LEVELS:
        return None
    middles_m = distance_m * (np.asarray(middles_rad) - bearing_rad)
    step_m = distance_m * float(np.median(np.abs(np.diff(scan.angles_rad))))
    noise_m2 = float(np.var(middles_m)) * (1.0 + 1.0 / middles_m.size)
    intensity_noise_m2 = None
    if scan.intensity_std is not None:
        spread = distance_m * gradient / len(middles_rad) * np.nan_to_num(scan.intensity_std)
        intensity_noise_m2 = float(spread @ spread)
    return EchoMiddle(
        float(np.mean(middles_rad)), float(np.mean(middles_m)), noise_m2, step_m, intensity_noise_m2
    )


def _across_from_echo_middle(
    scan: AveragedScan, fit: RodCentre, section: _Section, settings: ExtractionSettings
) -> RodCentre:
    """The centre with its position across the bearing from the middle of the rod's echo
    strength (``echo_middle`` at ``echo_middle_levels``). Along the bearing the centre is kept;
    across, the covariance takes the levels' scatter (a lopsided lobe's middles move with the
    level) and the mean's, and a beam step's quantisation besides (the beams' angles repeat at
    the pose); the dwell noise, what another dwell draws anew, is the averaged intensities'
    noise through the middle (``EchoMiddle.intensity_noise_m2``; the levels' scatter without
    intensity stds). The levels' scatter of one dwell is a poor measure of that: default job,
    seed 352, waypoint 12 (1.05 m), 24 dwells: the middle scattered 0.15 mm across while the
    levels' scatter read 0.011-0.30 mm, median 0.07, and the verify took a 0.3 mm difference
    for a move (chi-square 20.4). Unchanged where there is no middle. Not for a fluted rod (its
    glint is no symmetric lobe: ``find_rod_centre`` does not call it there; a twist drill's
    verify compares middles, ``verify/echo_reference``).

    The spot's power on the rod falls off alike on both sides of its centre; which echo wins
    at the rod's edges moves the segment's ends, not the lobe's middle (the dry run's waypoints
    1, 3, 17 and 18: within 0.2 mm of the true bearing, where the fits lay -0.75 to +1.32 mm)."""
    middle = echo_middle(scan, fit.centre_uv_m, section.semi_major_m, settings.echo_middle_levels)
    if middle is None:
        return fit
    # The centre at the fit's range on the middle's bearing: its along and across are the
    # middle's. (The fit's bearing for them tilted a near rod's long along std off the centre's
    # own: 45 mm polished rod at 0.1 m, a fit 9 mm aside, its ellipse 5 deg off, 12 mm along
    # read as 8 std.)
    centre_uv_m = middle.turned_onto(fit.centre_uv_m)
    across = _across_bearing(centre_uv_m)
    # A flat-topped lobe (every level crossed between the same two beams) fixes its middle only
    # to a beam step: each side anywhere within one, the middle their mean.
    along = np.outer(centre_uv_m, centre_uv_m) / float(centre_uv_m @ centre_uv_m)
    noise = fit.noise_covariance_uv_m2
    dwell_m2 = middle.noise_m2 if middle.intensity_noise_m2 is None else middle.intensity_noise_m2

    def across_replaced(covariance_uv_m2: FloatArray, across_m2: float) -> FloatArray:
        """The covariance's part along the bearing with ``across_m2`` across."""
        return along @ covariance_uv_m2 @ along + across_m2 * np.outer(across, across)

    return replace(
        fit,
        centre_uv_m=centre_uv_m,
        echo_middle_move_uv_m=centre_uv_m - fit.centre_uv_m,
        covariance_uv_m2=across_replaced(fit.covariance_uv_m2, middle.noise_m2 + middle.step_m**2 / 24.0),
        noise_covariance_uv_m2=None if noise is None else across_replaced(noise, dwell_m2),
    )


def _gloss_ratio(
    scan: AveragedScan,
    beams: NDArray[np.int64],
    centre_uv_m: FloatArray,
    radius_m: float,
    settings: ExtractionSettings,
) -> float | None:
    """How the rod's echo falls off across it against a diffuse (Lambert) section's: on the
    beams where a diffuse section would return under 0.9 of its brightest beam's, the median
    of each beam's intensity over the brightest, divided by that prediction (intensity goes
    as the square root of the power; the spot's core and halo as ``_spot_readings_m`` takes
    them). About 1 for a diffuse surface, well under for a polished one; None without
    intensities or such beams.

    The power is the one ``spot._spot_readings_m`` weights its readings by, integrated more
    plainly: an upright circle of ``radius_m`` (no tilt), one spot width for every beam (at the
    rod's front, ``distance - radius``), each beam beside the centre by its bearing, and 201
    angles over the visible half (where the spot model takes each beam's own section, range and
    Gauss-Legendre nodes within its spot). The two profiles differ by up to 0.4 % of the peak;
    ``glint_gloss_ratio`` was set on this one."""
    if scan.intensities is None:
        return None
    intensity = scan.intensities[beams]
    distance_m = float(np.linalg.norm(centre_uv_m))
    bearing_rad = float(np.arctan2(centre_uv_m[1], centre_uv_m[0]))
    offsets_m = distance_m * np.sin(scan.angles_rad[beams] - bearing_rad)
    half_m = 2.0 * float(_spot_sigma_m(np.array([distance_m - radius_m]), settings)[0])
    across_m = radius_m * np.sin(np.linspace(-np.pi / 2.0, np.pi / 2.0, 201))
    cosine = np.sqrt(np.fmax(1.0 - (across_m / radius_m) ** 2, 0.0))
    power = np.zeros(beams.size)
    for share, scale in _spot_parts(settings):
        width_m = max(half_m * scale, 1e-9)
        profile = np.exp(-2.0 * ((across_m[None, :] - offsets_m[:, None]) / width_m) ** 2)
        power += share / width_m * (profile * cosine * np.gradient(across_m)).sum(axis=1)
    predicted = np.sqrt(power / max(float(power.max()), 1e-300))
    flank = (predicted < 0.9) & np.isfinite(intensity)
    if not np.any(flank) or not np.nanmax(intensity) > 0.0:
        return None
    return float(np.median(intensity[flank] / np.nanmax(intensity) / predicted[flank]))


def _along_from_glint(
    scan: AveragedScan, found: RodCentre, section: _Section, settings: ExtractionSettings
) -> RodCentre:
    """A polished rod on few beams (``glint_gloss_ratio``, ``glint_max_beams``) placed along its
    bearing by its glint: its brightest beam reads the section's front, which lies the
    section's half-width along the bearing (a radius for an upright rod) before the centre.
    The covariance keeps the fit's along the bearing, plus ``spot_model_doubt`` of the move
    (the glint is not a mirror's point: the spot's middle, not its peak) and the beam's own
    noise, which the dwell's noise takes too. Unchanged otherwise."""
    beams = found.beam_indices
    if scan.intensities is None or not 0 < beams.size <= settings.glint_max_beams:
        return found
    gloss = _gloss_ratio(scan, beams, found.centre_uv_m, section.radius_m, settings)
    if gloss is None or gloss >= settings.glint_gloss_ratio:
        return found
    brightest = int(beams[int(np.nanargmax(scan.intensities[beams]))])
    bearing = found.centre_uv_m / float(np.linalg.norm(found.centre_uv_m))
    front_m = section.radius_m * float(np.linalg.norm(section.from_circle(bearing[None, :])[0]))
    shift_m = float(scan.ranges_m[brightest]) + front_m - float(np.linalg.norm(found.centre_uv_m))
    beam_m2 = float(_range_sigma(scan, settings)[brightest]) ** 2
    along = np.outer(bearing, bearing)
    doubt_m2 = (settings.spot_model_doubt * shift_m) ** 2 + beam_m2
    noise = found.noise_covariance_uv_m2
    return replace(
        found,
        centre_uv_m=found.centre_uv_m + shift_m * bearing,
        covariance_uv_m2=found.covariance_uv_m2 + doubt_m2 * along,
        noise_covariance_uv_m2=None if noise is None else noise + beam_m2 * along,
    )
