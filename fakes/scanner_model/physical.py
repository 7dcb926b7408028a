"""The physical UTM-30LX-EW: footprint, echo, intensity, noise, bias, drift, per scan.

``PhysicalScanner`` holds the beam layout (``K`` sub-rays per beam: parallel offsets across
the exit aperture plus the divergence, so the spot is ``w0 + divergence * range`` wide)
and the static scene cast once.  ``scan`` adds the moving shapes (the rod, the chuck),
lets each beam's footprint return its light (``materials``), picks the echo the scanner
reports (``echo``), and adds the range error (``range_error``).  docs/scanner-model.md
describes the model and the source of every parameter.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fakes.raycast import beams_near_sphere
from fakes.scanner_model.echo import Echoes, detect_echo
from fakes.scanner_model.materials import backscatter
from fakes.scanner_model.range_error import range_bias_m, range_sigma_m, warmup_drift_m
from fakes.scene import PhysicsSettings
from fakes.shapes import Shape, SurfaceHit
from lasercal_hw.models import FloatArray

MovingShape = tuple[Shape, FloatArray, float]
"""A shape that moves with the robot, the centre and radius of a sphere bounding it."""

#: A beam whose sub-rays (by weight) meet one surface at least this much is wholly on it: no
#: speckle from scan to scan (a real unit's steady beams: docs/scanner-model.md).
WHOLE_BEAM_SHARE = 0.99


class PhysicalScanner:
    """Beams of a UTM-30LX-EW with a real footprint, looking at a static scene."""

    def __init__(self, physics: PhysicsSettings, angles_rad: FloatArray, static: Sequence[Shape]) -> None:
        self.physics = physics
        self.angles_rad = np.asarray(angles_rad, dtype=float)
        self._u, self._du, self._weights = beam_profile(physics)
        angles = self.angles_rad[:, None] + 0.5 * physics.divergence_rad * self._u[None, :]
        self._dirs = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], -1)
        beam = self.angles_rad
        self._across = np.stack([-np.sin(beam), np.cos(beam), np.zeros_like(beam)], -1)
        offsets_m = 0.5 * physics.spot_width_at_scanner_m * self._u
        self._origins = offsets_m[None, :, None] * self._across[:, None, :]
        self._static_count = len(static)
        every_beam = np.arange(self.angles_rad.size)
        self._static_t, self._static_power, self._static_id = self._cast(list(static), every_beam)
        # The static scene's echoes are found once: static depth edges keep their mixed
        # value (flips are modelled where the moving shapes are).
        static_echo = detect_echo(
            self._static_t, self._static_power, physics.pulse_fwhm_m, 0.0, physics.echo_choice
        )
        self._static_range, self._static_peak = static_echo.range_m, static_echo.peak
        self._pose: _PoseCache | None = None

    def _cast(
        self, shapes: list[Shape], beams: NDArray[np.int64]
    ) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
        """Nearest hit of every sub-ray of ``beams``, the power it returns, the shape's index."""
        k = self._u.size
        dirs = self._dirs[beams].reshape(-1, 3)
        origins = self._origins[beams].reshape(-1, 3)
        lateral = np.repeat(self._across[beams], k, axis=0)
        du = np.tile(self._du, beams.size)
        best_t = np.full(dirs.shape[0], np.inf)
        best_power = np.zeros(dirs.shape[0])
        best_id = np.full(dirs.shape[0], -1, dtype=np.int64)
        for index, shape in enumerate(shapes):
            hit = shape.surface_hit(dirs, origins, lateral)
            nearer = hit.t < best_t
            if nearer.any():
                best_t = np.where(nearer, hit.t, best_t)
                best_power = np.where(nearer, self._power(hit, du, shape.material), best_power)
                best_id = np.where(nearer, index, best_id)
        power = best_power.reshape(-1, k) * self._weights[None, :]
        return best_t.reshape(-1, k), power, best_id.reshape(-1, k)

    def _power(self, hit: SurfaceHit, du: FloatArray, material: str) -> FloatArray:
        """Received power relative to white Kent sheet at 1 m: back-scatter over each
        sub-ray's strip of the spot (``du`` wide in spot units, ``beam_profile``), 1/r^2,
        and the receiver's overlap with the beam, which starves the nearest range."""
        p = self.physics
        r = np.fmax(np.where(np.isfinite(hit.t), hit.t, 1.0), 1e-3)
        half_strip_m = 0.25 * du * (p.spot_width_at_scanner_m + p.divergence_rad * r)
        scatter = backscatter(material, hit.cos, hit.section_cos, hit.turn_rad_per_m * half_strip_m)
        return scatter * receiver_overlap(r, p) / r**2

    def _pose_cache(self, moving: Sequence[MovingShape], threshold: float) -> _PoseCache:
        """Cast the moving shapes once per pose (a dwell scans one pose many times) and find
        their echoes without speckle; rows whose two strongest lobes are close, or whose spot
        is split at an edge, are marked."""
        key = b"".join(np.asarray(v).tobytes() for shape, _, _ in moving for v in shape.params)
        if self._pose is not None and self._pose.key == key:
            return self._pose
        near = [self.beams_near(centre, radius) for _, centre, radius in moving]
        beams = np.unique(np.concatenate([np.zeros(0, np.int64), *near])).astype(np.int64)
        t, power, ids = self._static_t[beams], self._static_power[beams], self._static_id[beams]
        if beams.size and moving:
            moving_t, moving_power, moving_id = self._cast([shape for shape, _, _ in moving], beams)
            nearer = moving_t < t
            touched = nearer.any(axis=1)  # the bounding spheres are generous: keep real hits
            beams, nearer = beams[touched], nearer[touched]
            t = np.where(nearer, moving_t[touched], t[touched])
            power = np.where(nearer, moving_power[touched], power[touched])
            ids = np.where(nearer, self._static_count + moving_id[touched], ids[touched])
        ids = np.where(ids >= 0, ids, 0)
        p = self.physics
        echo = detect_echo(t, power, p.pulse_fwhm_m, threshold, p.echo_choice)
        power_by_surface = np.zeros((beams.size, self._static_count + len(moving) + 1))
        rows = np.repeat(np.arange(beams.size), ids.shape[1])
        np.add.at(power_by_surface, (rows, ids.ravel()), power.ravel())
        surface = np.argmax(power_by_surface, axis=1)
        contest = np.exp(-3.0 * np.sqrt(2.0) * p.speckle_sigma)
        contested = np.flatnonzero((echo.rival > 0.0) & (echo.rival >= contest * echo.peak))
        on_surface = np.isfinite(t) & (ids == surface[:, None])
        split = (on_surface * self._weights).sum(axis=1) < WHOLE_BEAM_SHARE * self._weights.sum()
        self._pose = _PoseCache(key, beams, t, power, ids, echo, surface, contested, split)
        return self._pose

    def beams_near(self, centre_m: FloatArray, radius_m: float) -> NDArray[np.int64]:
        """Beams whose footprint can touch a sphere (the beam's own width included)."""
        distance = float(np.linalg.norm(centre_m[:2])) + radius_m
        margin = 0.5 * (self.physics.spot_width_at_scanner_m + self.physics.divergence_rad * distance)
        return beams_near_sphere(self.angles_rad, centre_m, radius_m + margin)

    def scan(
        self,
        moving: Sequence[MovingShape],
        rng: np.random.Generator | None,
        elapsed_s: float | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """Ranges (m, inf: no echo) and intensities (device units) of one revolution.

        ``moving``: shapes that move with the robot, each with a bounding sphere; ``rng``:
        None for the noise-free scan (no speckle, noise, drift or duplicated steps, but
        footprint, mixed pixels and bias are there: they are deterministic).
        """
        p = self.physics
        threshold = (p.detection_threshold / p.intensity_at_1m) ** 2
        ranges = self._static_range.copy()
        peak = self._static_peak.copy()
        pose = self._pose_cache(moving, threshold)
        if pose.beams.size:
            ranges[pose.beams] = pose.echo.range_m
            peak[pose.beams] = pose.echo.peak
        if pose.beams.size and rng is not None and p.speckle_sigma > 0.0:
            # This scan's speckle on each surface's power reaches a beam at an edge (its spot
            # split between surfaces, or partly on none: its power moves, near the threshold it
            # comes and goes) and, where two lobes compete, picks the winner (re-detected). A
            # beam wholly on one surface keeps its power: a real unit's intensity there
            # scatters 0.8 % from reading to reading (``intensity_noise``).
            shape = (pose.beams.size, self._static_count + len(moving) + 1)
            speckle = np.exp(rng.normal(-0.5 * p.speckle_sigma**2, p.speckle_sigma, shape))
            own = speckle[np.arange(pose.beams.size), pose.surface]
            peak[pose.beams] *= np.where(pose.split, own, 1.0)
            rows = pose.contested
            if rows.size:
                scale = np.take_along_axis(speckle[rows], pose.ids[rows], axis=1)
                power = pose.power[rows] * scale
                echo = detect_echo(pose.t[rows], power, p.pulse_fwhm_m, threshold, p.echo_choice)
                ranges[pose.beams[rows]], peak[pose.beams[rows]] = echo.range_m, echo.peak
        ranges = np.where(peak >= threshold, ranges, np.inf)
        intensity = intensity_for(p, peak)
        found = np.isfinite(ranges)
        ranges[found] += range_bias_m(ranges[found], intensity[found], p)
        if rng is not None:
            ranges[found] += warmup_drift_m(elapsed_s, p)
            ranges[found] += rng.normal(0.0, 1.0, int(found.sum())) * range_sigma_m(intensity[found], p)
            intensity = intensity * (1.0 + p.intensity_noise * rng.normal(0.0, 1.0, intensity.size))
            ranges, intensity = _duplicate_steps(ranges, intensity, p.duplicate_step_probability, rng)
        return ranges, np.where(np.isfinite(ranges), np.fmax(intensity, 0.0), 0.0)


def beam_profile(physics: PhysicsSettings) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Sub-ray positions across the spot (1 = the core's 1/e^2 edge), the width of the
    strip of the spot each stands for (same unit) and their weights (the strip's power).

    The profile is a gaussian core plus a wider, faint halo (``halo_fraction`` of the
    power, ``halo_scale`` times wider): a real laser spot's skirt, which a bright surface
    (retro-reflective tape) lights up far beyond the core.  The spot is cut into strips
    that tile it, narrower in the core (sinh spacing) and spanning the halo; each sub-ray
    runs through the middle of its strip (the midpoint rule: a glint anywhere on the spot
    falls in exactly one strip, ``materials.backscatter``).
    """
    k = physics.sub_rays
    if k == 1:
        return np.zeros(1), np.full(1, 2.0), np.ones(1)
    span = physics.halo_scale if physics.halo_fraction > 0.0 else 1.0
    x = np.linspace(-1.0, 1.0, k + 1)
    stretch = 2.0 if span > 1.0 else 1e-6
    edges = span * np.sinh(stretch * x) / np.sinh(stretch)
    u = 0.5 * (edges[1:] + edges[:-1])
    du = np.diff(edges)
    core = np.exp(-2.0 * u**2)
    halo = np.exp(-2.0 * (u / physics.halo_scale) ** 2) / physics.halo_scale
    profile = (1.0 - physics.halo_fraction) * core + physics.halo_fraction * halo
    weights = profile * du
    return u, du, weights / weights.sum()


@dataclass(frozen=True)
class _PoseCache:
    """The moving shapes' beams at one pose: sub-ray ranges, powers, surface ids, the
    speckle-free echo, each beam's brightest surface, the rows whose two strongest lobes are
    close and the rows whose spot is split at an edge."""

    key: bytes
    beams: NDArray[np.int64]
    t: FloatArray
    power: FloatArray
    ids: NDArray[np.int64]
    echo: Echoes
    surface: NDArray[np.int64]
    contested: NDArray[np.int64]
    split: NDArray[np.bool_]


def _duplicate_steps(
    ranges: FloatArray, intensity: FloatArray, probability: float, rng: np.random.Generator
) -> tuple[FloatArray, FloatArray]:
    """Some steps repeat the previous step's reading exactly (range and intensity), as
    the UTM-30LX-EW's own logs show."""
    if probability <= 0.0:
        return ranges, intensity
    repeat = rng.random(ranges.size) < probability
    repeat[0] = False
    source = np.maximum.accumulate(np.where(repeat, 0, np.arange(ranges.size)))
    return ranges[source], intensity[source]


def receiver_overlap(range_m: FloatArray, physics: PhysicsSettings) -> FloatArray:
    """Share of the returned light the receiver sees: the beam leaves beside the receiving
    lens, so the nearest targets fall outside its view (``1 / (1 + (r0 / r)^4)``)."""
    if physics.overlap_range_m <= 0.0:
        return np.ones_like(range_m)
    return 1.0 / (1.0 + (physics.overlap_range_m / np.fmax(range_m, 1e-3)) ** 4)


def intensity_for(physics: PhysicsSettings, power: FloatArray) -> FloatArray:
    """Device intensity for a received power (white Kent sheet at 1 m = 1): the UTM's
    intensity grows like the square root of the power (measured: docs/scanner-model.md)."""
    return np.fmin(physics.intensity_at_1m * np.sqrt(power), physics.intensity_max)
