"""The extraction benchmark's reference line: how often an exactly right covariance meets issue
18's band and "no silent centre", checked against the closed forms."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from benchmarks.extraction_physical import BAND, OFF_STD, WITHIN_STD, honest_odds

TRIALS = 20000


def _within(measured: float, expected: float) -> bool:
    """Within four standard errors of a Monte Carlo frequency over ``TRIALS``."""
    return abs(measured - expected) <= 4.0 * math.sqrt(expected * (1.0 - expected) / TRIALS) + 1e-9


def test_the_odds_match_the_closed_forms() -> None:
    centres = 258
    band, silent_free, both = honest_odds(centres, trials=TRIALS, seed=3)
    # A 2-D gaussian's Mahalanobis distance exceeds d with probability exp(-d^2 / 2).
    assert _within(silent_free, (1.0 - math.exp(-(OFF_STD**2) / 2.0)) ** centres)
    # The band's upper edge: at least 1 % of the 2N components beyond 2.5 std (the lower edge,
    # 10 %, is never reached by a right covariance).
    components = 2 * centres
    beyond = 2.0 * stats.norm.sf(WITHIN_STD)
    fewest_beyond = math.ceil(components * (1.0 - BAND[1]) - 1e-9)
    assert _within(band, float(stats.binom.sf(fewest_beyond - 1, components, beyond)))
    assert both <= min(band, silent_free)


def test_a_wider_reported_std_trades_the_band_for_no_silent_centre() -> None:
    narrow = honest_odds(258, ratio=1.2, trials=2000)
    wide = honest_odds(258, ratio=0.8, trials=2000)
    assert narrow[0] > 0.99 and narrow[1] < 0.01
    assert wide[0] < 0.01 and wide[1] > 0.7
    assert np.isclose(wide[2], 0.0, atol=0.005)
