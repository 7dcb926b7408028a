"""A twist drill (``fluted``): its centre moved to where its axis lies on average over its turn,
its covariance widened by how far off that may be."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from lasercal_hw.scan.extraction.results import RodCentre
from lasercal_hw.scan.extraction.section import _Section
from lasercal_hw.scan.extraction.settings import ExtractionSettings


def _flute_moments_m(radius_m: float, settings: ExtractionSettings) -> tuple[float, float, float]:
    """Where a twist drill's axis lies from the centre a circle fit finds on it, over the
    drill's turn about its axis (unknown to the extraction): the mean and variance along the
    bearing (away from the scanner) and the variance across it, in m and m^2.

    The fit puts a circle of the drill's radius behind the surface the echo comes from. A
    land facing the scanner is on that circle; a flute facing it (a share ``2 opening / 360``
    of the turns) sends its echo from its hollow, ``(1 - web) r`` deeper, and aside by ``r
    sin(delta)`` where the flute's middle is turned ``delta`` (uniform over the opening) from
    the scanner. On the physical scanner model's polished 10 mm bit (drill job, seeds
    100-102) the centres lay 0 mm (land facing) to 5.7 mm (flute facing) behind the axis along
    the bearing, 2.4 mm std, and 1.4 mm RMS across it."""
    half_rad = np.radians(settings.flute_opening_deg) / 2.0
    share = 2.0 * half_rad / np.pi
    depth_m = (1.0 - settings.flute_web_fraction) * radius_m
    across_m2 = share * radius_m**2 * (0.5 - np.sin(2.0 * half_rad) / (4.0 * half_rad))
    return share * depth_m, share * (1.0 - share) * depth_m**2, float(across_m2)


def _with_flutes(found: RodCentre, section: _Section, settings: ExtractionSettings) -> RodCentre:
    """A centre fitted on a twist drill moved to where its axis lies on average and its
    covariance widened by how far off that may be (``_flute_moments_m``), both stretched
    along the section's major axis for a tilted drill. The error repeats at the same pose and
    turn, so the noise part of the covariance stays."""
    mean_m, along_m2, across_m2 = _flute_moments_m(section.radius_m, settings)
    bearing = found.centre_uv_m / float(np.linalg.norm(found.centre_uv_m))
    across = np.array([-bearing[1], bearing[0]])
    stretch = section.from_circle(np.eye(2)).T  # the linear map from the circle to the section
    shift = stretch @ (-mean_m * bearing)  # the fit lies behind the axis: move it nearer
    covariance = stretch @ (along_m2 * np.outer(bearing, bearing) + across_m2 * np.outer(across, across))
    return replace(
        found,
        centre_uv_m=found.centre_uv_m + shift,
        covariance_uv_m2=found.covariance_uv_m2 + covariance @ stretch.T,
    )
