"""Real SCIP 2.0 device captures (scip_captures.md section A) used as golden test data."""

from __future__ import annotations

import base64
from pathlib import Path

DATA_DIR = Path(__file__).parent / "data" / "scip"

UTM30LX_ECHOES = [b"VV", b"VV", b"PP", b"II", b"BM", b"CR00", b"VV", b"PP", b"II",
                  b"ME0000108001101", b"ME0000108001100"]
URG04LX_ECHOES = [b"VV", b"VV", b"PP", b"II", b"BM", b"CR00", b"VV", b"PP", b"II", b"GD0044072501"]
UXM30LXE_ECHOES = [b"VV", b"VV", b"PP", b"II", b"TM0", *[b"TM1"] * 10, b"TM2", b"BM", b"CR00",
                   b"VV", b"PP", b"II", b"GD0000076001"]


def capture(name: str) -> bytes:
    """Raw bytes of ``tests/data/scip/<name>.b64`` (e.g. ``utm30lx_read``)."""
    return base64.b64decode("".join((DATA_DIR / f"{name}.b64").read_text().split()))
