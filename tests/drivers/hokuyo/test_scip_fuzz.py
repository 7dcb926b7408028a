"""The driver against 1,000 seeded mutated SCIP conversations (issue 14): no crash, no
hang, and never wrong data accepted where a checksum could see the damage."""

from __future__ import annotations

import pytest

from tests.scip_fuzz import run_many

pytestmark = pytest.mark.timeout(300)


def test_a_thousand_damaged_conversations_end_cleanly_or_with_the_true_data() -> None:
    counts, details, _ = run_many(1000)
    assert counts["crash"] == 0, details.get("crash", [])[:5]
    assert counts["hang"] == 0, details.get("hang", [])[:5]
    assert counts["wrong_detectable"] == 0, details.get("wrong_detectable", [])[:5]
    # The plan exercises both ends: refusals, and damage the driver recovers from (retries,
    # resynchronisation); what a 6-bit sum cannot see (a byte moved by 64, swapped data
    # lines) stays rare.
    assert counts["clean_error"] > 300 and counts["recovered"] > 300, counts
    assert counts["wrong_undetectable"] < 20, details.get("wrong_undetectable", [])
