"""How much of a plain fit's stated dwell noise a dwell of a twist drill really draws anew, from
the run's own scans (docs/verify.md, ``dwellnoise``).

A plain fit of the fluted section states its noise as the fit's noise covariance scaled up by
its reduced chi-square (``scan.extraction.covariance``), and the misfit there is mostly the
section's shape, which repeats at the same pose and view: the stated noise is too wide, and the
verify's drift test, which weighs every residual with it, loses its power. Without the scaling
it is too narrow (which beams the fit keeps, and the shape's share in what they read, change a
little from dwell to dwell).

So the run measures it: every waypoint's dwell averaged as its even and its odd scans apart
(``AveragedScan.halves``), both fitted again as its centre was, and their difference ``d``
weighed with the centre's stated noise ``N``. Were a dwell's centre noise ``f N``, each half's
would be ``2 f N`` (its beams' noise averages over half the scans) and ``d``'s ``4 f N``, so
``d^T N^-1 d / 4`` has the mean ``2 f``: pooled over the waypoints, ``f`` with two degrees of
freedom per waypoint. The factor is kept at most 1 (the stated noise is the bound the fit
vouches for) and the drift test takes its own scatter into its threshold (``DwellNoiseScale.dof``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from lasercal_hw.run.records import WaypointMeasurement
from lasercal_hw.scan.extraction import RodCentre

#: Fewer waypoints than this with both halves fitted leave the stated noise as it is.
MIN_WAYPOINTS = 10

#: Fits measurements again (``SecondPassRefit.centres`` as the run fitted its centres): the
#: measurements with their new centres, and the (index, reason) of those it could not fit.
Refit = Callable[[list[WaypointMeasurement]], tuple[list[WaypointMeasurement], list[tuple[int, str]]]]


@dataclass(frozen=True)
class DwellNoiseScale:
    """The stated dwell noise times ``factor`` is what a dwell draws anew; ``dof``: the
    degrees of freedom it pools (0: not measured, the factor 1)."""

    factor: float = 1.0
    dof: int = 0

    def note(self) -> str:
        """What the run says of it (its ``refinement``)."""
        if not self.dof:
            return f"the plain fits' stated dwell noise kept (fewer than {MIN_WAYPOINTS} half dwells fitted)"
        if self.factor == 1.0:
            return f"the plain fits' stated dwell noise kept ({self.dof // 2} half dwells scatter as much)"
        return (
            f"the plain fits' stated dwell noise times {self.factor:.2f}, as their half dwells scatter "
            f"({self.dof // 2} waypoints)"
        )

    def scaled(self, centre: RodCentre) -> RodCentre:
        """``centre`` with its stated dwell noise scaled; one the extraction warns of keeps it
        (``RodCentre.dwell_noise_covariance_uv_m2`` takes its whole covariance)."""
        noise = centre.noise_covariance_uv_m2
        if noise is None or centre.warnings or self.factor == 1.0:
            return centre
        return replace(centre, noise_covariance_uv_m2=self.factor * np.asarray(noise, dtype=float))


#: Each waypoint's two half dwells' centres, by its index.
HalfCentres = dict[int, tuple[RodCentre, RodCentre]]


def half_centres(measurements: Sequence[WaypointMeasurement], refit: Refit) -> HalfCentres:
    """Both halves' centres (fitted by ``refit``) of each measurement whose dwell kept its halves
    and whose centre states its noise without a warning, where both halves fitted."""
    chosen = [
        m
        for m in measurements
        if m.averaged.halves is not None
        and m.centre.noise_covariance_uv_m2 is not None
        and not m.centre.warnings
    ]
    fits: list[dict[int, RodCentre]] = []
    for which in (0, 1):
        halved = [replace(m, averaged=m.averaged.halves[which]) for m in chosen]  # type: ignore[index]
        fitted, failed = refit(halved)
        unfitted = {index for index, _ in failed}
        fits.append({m.index: m.centre for m in fitted if m.index not in unfitted})
    return {index: (fits[0][index], fits[1][index]) for index in fits[0] if index in fits[1]}


def steady(measurement: WaypointMeasurement, halves: HalfCentres) -> bool:
    """Both halves' fits kept the beams the dwell's fit kept. A fluted centre jumps by millimetres
    where its beam set changes by one beam, which another dwell may do (drill job, seeds 104-109:
    unmoved verifies at 17-41 in chi-square with every centre scaled); a centre whose own halves
    already disagree on its beams keeps its stated noise whole."""
    both = halves.get(measurement.index)
    beams = measurement.centre.beam_indices
    return both is not None and all(np.array_equal(half.beam_indices, beams) for half in both)


def measured_scale(
    measurements: Sequence[WaypointMeasurement], halves: HalfCentres
) -> DwellNoiseScale:
    """The factor (module docstring) pooled over the steady ``measurements`` (``steady``)."""
    squares = []
    for m in measurements:
        if not steady(m, halves):
            continue
        even, odd = halves[m.index]
        d = np.asarray(even.centre_uv_m, dtype=float) - np.asarray(odd.centre_uv_m, dtype=float)
        noise = np.asarray(m.centre.noise_covariance_uv_m2, dtype=float)
        squares.append(float(d @ np.linalg.solve(noise, d)) / 4.0)
    if len(squares) < MIN_WAYPOINTS:
        return DwellNoiseScale()
    return DwellNoiseScale(min(1.0, float(np.sum(squares)) / (2.0 * len(squares))), 2 * len(squares))


def with_measured_noise(
    measurements: Sequence[WaypointMeasurement],
    scale: DwellNoiseScale,
    halves: HalfCentres,
) -> list[WaypointMeasurement]:
    """The measurements, each steady one's stated dwell noise scaled (``DwellNoiseScale.scaled``)."""
    return [replace(m, centre=scale.scaled(m.centre)) if steady(m, halves) else m for m in measurements]
