"""The pull of a surface a pulse length behind a rod (``echo_pull``) against the scanner model's
own echo detection (``fakes/scanner_model/echo.py``): the same physics, read back."""

from __future__ import annotations

import numpy as np
import pytest

from fakes.scanner_model.echo import detect_echo
from lasercal_hw.scan.echo_pull import surface_share, tail_pull_m

PULSE_FWHM_M = 1.0
SIGMA_M = PULSE_FWHM_M / (2.0 * np.sqrt(2.0 * np.log(2.0)))


@pytest.mark.parametrize(("share", "depth_m"), [(0.05, 0.9), (0.2, 1.0), (0.35, 1.1), (0.3, 1.5)])
def test_the_pull_is_where_the_model_puts_the_rods_echo_peak(share: float, depth_m: float) -> None:
    # The rod at 0 with 1 - share of the power, the surface depth_m behind with share: the model
    # reports the rod's lobe (the stronger), its peak pulled towards the surface.
    t_m = np.array([[0.5, 0.5 + depth_m]])
    power = np.array([[1.0 - share, share]])
    reported = detect_echo(t_m, power, PULSE_FWHM_M, threshold=0.0).range_m[0]
    pull = tail_pull_m(np.array([share]), np.array([depth_m]), PULSE_FWHM_M)[0]
    assert pull == pytest.approx(reported - 0.5, abs=1e-4)
    assert pull > 0.0


def test_the_surfaces_share_is_of_the_rod_and_the_surface_together() -> None:
    # Beyond the merge the beam's intensity is the rod's lobe: its peak carries only the pulse's
    # tail of the surface's power. A surface as strong as the rod is half the power, not all of it
    # (the ratio, taken for the share, read equal lobes where the rod's lobe is twice the other).
    rod, surface_full, beside, depth_m = 1.0, 2.0, 0.25, 1.0
    surface = beside * surface_full
    tail = np.exp(-0.5 * (depth_m / SIGMA_M) ** 2)
    intensity = np.sqrt(rod + tail * surface)
    share = surface_share(
        np.array([beside]), np.array([intensity]), np.array([np.sqrt(surface_full)]), np.array([depth_m]),
        PULSE_FWHM_M,
    )[0]
    assert share == pytest.approx(surface / (rod + surface))
