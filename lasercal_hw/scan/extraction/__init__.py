"""Rod centre from an averaged scan: segment the rod, drop mixed pixels, fit its centre.

Steps (docs/extraction.md has the reasoning):

1. Segment: with a background scan, beams significantly nearer than the background (per-
   beam noise of both scans); without one, runs of valid beams split at range jumps.
   The rod's own beams are picked out of each run (steady mixed-pixel ramps beside it cut
   off: ``_rod_core``). A candidate must stand in front of its neighbours and span the
   angle a rod of the known radius covers at its range. Every candidate is fitted: the
   fit nearest ``expected_uv_m`` wins if within the search radius (others are refused by
   name); without an expected position two rod-like fits are a refusal naming both.
2. Seed: mean of the arc points plus the paper's ``R*pi/4`` correction away from the
   scanner (exact for a far rod whose beams sample the half circle evenly across).
3. Fit: Gauss-Newton on the orthogonal distance of each point to the rod's surface,
   ``dist(point, axis line) - r``, with the axis through the unknown centre (u, v, 0).
   With ``axis_in_scanner`` the line is tilted and the cross-section is the ellipse
   (semi-minor r, semi-major r/|cos tilt|); without it the line is the scanner z axis
   and the cross-section a circle.  Each residual is weighted by the range noise
   projected on the surface normal plus a small lateral (beam-angle) term.  The
   covariance adds what the dwell does not average away (residuals beyond the noise) and
   how far the solver's range-error model is from this fit's response to a range error.
   Then the same fit against what each beam's spot returns from the rod (its power-weighted
   mean over the curved front: ``_spot_readings_m``) gives the centre along the bearing,
   the ray fit across it (``_along_the_spot``), unless the rays fit the beams better.
4. Mixed pixels: unstable beams (their readings flipped between rod and background
   during the dwell: a low inlier count or a reading spread far above the scan's) are
   trimmed off the ends of every segment before it is judged; after the fit, edge beams
   lying significantly behind the fitted surface are dropped and the fit repeated.
5. Radius: a free-radius fit when enough beams over a wide enough arc hit the rod.
6. The beam's spot (wider than a thin rod): a near rod looks up to a spot wider (allowed in
   the size check; the core is centred in that halo, and a flat bright blot's middle is its
   front); a background close behind merges into the echo, bounded per beam by its share of the spot
   (and intensities) times the depth: a rod no beam reads alone is refused, one whose
   cleanest beam is still partly background gets the bound in its covariance and a warning.
   What the range-error curve leaves across the arc (range walk, near-range error) joins
   the covariance too, and so does what two sideways checks find (the arc without its edge
   beams; for a fit of few beams, the range profile's symmetry).

Modules, one job each (names with a leading underscore are this package's own, not for its
callers): ``find`` (the entry point), ``candidates`` (segmentation), ``cores`` (the rod's own
beams in a segment), ``size`` (how wide a rod looks), ``beams`` (per-beam noise, unstable
beams), ``segment_fit`` (one candidate fitted), ``centre_fit`` (a centre from points), ``fit``
(Gauss-Newton against rays or the spot), ``spot`` (the beam's spot), ``spot_fit`` (along the
bearing from the spot), ``covariance`` (a fit's covariances), ``blend`` (the surface behind),
``doubts`` (what the covariance adds), ``intensity`` (the echo's strength), ``drill`` (a twist
drill), ``diagnose`` (refusals in words), ``section`` (the cross-section), ``results`` and
``settings``.
"""

from __future__ import annotations

from lasercal_hw.scan.extraction.centre_fit import seed_centre_pi4
from lasercal_hw.scan.extraction.find import find_rod_centre
from lasercal_hw.scan.extraction.intensity import EchoMiddle, echo_middle
from lasercal_hw.scan.extraction.results import RodCentre, RodNotFoundError, RodQuality
from lasercal_hw.scan.extraction.settings import ExtractionSettings

__all__ = [
    "EchoMiddle",
    "ExtractionSettings",
    "RodCentre",
    "RodNotFoundError",
    "RodQuality",
    "echo_middle",
    "find_rod_centre",
    "seed_centre_pi4",
]
