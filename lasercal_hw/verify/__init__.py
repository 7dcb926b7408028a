"""``lasercal verify``: is the active calibration still right? (docs/verify.md)

``verify(VerifyRequest(...), "result.json", on_event=..., cancel=...) -> VerifyReport``
with ``.verdict`` (ok | inconclusive | degraded | recalibrate, and the reason) and ``.document()``.
"""

from __future__ import annotations

from lasercal_hw.verify.procedure import VerifyReport, VerifyRequest, verify

__all__ = ["VerifyReport", "VerifyRequest", "verify"]
