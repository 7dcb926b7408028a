"""What the fake scanner says about itself in VV, PP and II (scip2.md 4.1-4.3).

Two presets: ``UTM_30LX_EW`` (the default; PP is the UTM-30LX-EW message of
scip_captures.md B.3 byte for byte, VV/II follow scip2.md's recommendations) and
``UTM_30LX_CAPTURED`` (reproduces the real UTM-30LX replies of scip_captures.md A.1, so
a test can compare bytes). Every string is a field, so other identities are one
``dataclasses.replace`` away.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, replace
from enum import Enum

from fakes.scene import DEFAULT_SCANNER_NAME


class SensorState(Enum):
    """Measurement states of scip2.md section 8."""

    IDLE = "idle"
    """Laser off (power-up state, after QT/RS, after a finite MD/ME)."""
    MEASURING = "measuring"
    """Laser on after BM; GD/GE allowed."""
    STREAMING = "streaming"
    """MD/MS/ME running (laser on)."""
    TIME_ADJUST = "time_adjust"
    """Between TM0 and TM2 (laser off)."""


class LinkKind(Enum):
    """How the host is connected: decides SS and the II ``SBPS`` text."""

    ETHERNET = "ethernet"
    SERIAL = "serial"


@dataclass(frozen=True)
class ScipIdentity:
    """VV, PP and II contents. ``ii_time_format`` is ``"hex"`` (6 upper-case hex digits,
    as every captured URG/UTM) or ``"scip"`` (4-char encoding, as UST units)."""

    vendor: str
    product: str
    firmware: str
    protocol: str
    serial: str
    pp_model: str
    ii_model: str
    min_range_mm: int = 23
    max_range_mm: int = 60000
    steps_per_revolution: int = 1440
    first_step: int = 0
    last_step: int = 1080
    front_step: int = 540
    motor_speed_rpm: int = 2400
    ii_motor_speed: str = "2400"
    ii_mode_idle: str = "000 Idle"
    ii_mode_measuring: str = "003 Single_scan"
    ii_mode_streaming: str = "004 Multi_scan"
    ii_mode_time_adjust: str = "002 Time_adjustment"
    ii_link_ethernet: str = "Ethernet 100 [Mbps]"
    ii_link_serial: str = "USB Full Speed"
    ii_status: str = "Stable 000 no error."
    ii_time_format: str = "hex"

    def __post_init__(self) -> None:
        if self.ii_time_format not in ("hex", "scip"):
            raise ValueError(f"ii_time_format must be 'hex' or 'scip', not {self.ii_time_format!r}")

    def version_fields(self) -> list[tuple[str, str]]:
        """VV lines, in order."""
        return [
            ("VEND", self.vendor),
            ("PROD", self.product),
            ("FIRM", self.firmware),
            ("PROT", self.protocol),
            ("SERI", self.serial),
        ]

    def parameter_fields(self) -> list[tuple[str, str]]:
        """PP lines, in order."""
        return [
            ("MODL", self.pp_model),
            ("DMIN", str(self.min_range_mm)),
            ("DMAX", str(self.max_range_mm)),
            ("ARES", str(self.steps_per_revolution)),
            ("AMIN", str(self.first_step)),
            ("AMAX", str(self.last_step)),
            ("AFRT", str(self.front_step)),
            ("SCAN", str(self.motor_speed_rpm)),
        ]

    def mode_text(self, state: SensorState) -> str:
        """II ``MESM`` value for a state."""
        return {
            SensorState.IDLE: self.ii_mode_idle,
            SensorState.MEASURING: self.ii_mode_measuring,
            SensorState.STREAMING: self.ii_mode_streaming,
            SensorState.TIME_ADJUST: self.ii_mode_time_adjust,
        }[state]

    def link_text(self, link: LinkKind) -> str:
        """II ``SBPS`` value for a link."""
        return self.ii_link_ethernet if link is LinkKind.ETHERNET else self.ii_link_serial


UTM_30LX_EW = ScipIdentity(
    vendor="Hokuyo Automatic Co.,Ltd.",
    product="SOKUIKI Sensor TOP-URG UTM-30LX-EW",
    firmware="1.1.0 (2011-09-30)",
    protocol="SCIP 2.0",
    serial="H0123456",
    pp_model="UTM-30LX-EW",
    ii_model="UTM-30LX-EW",
)
"""Default identity. PP = scip_captures.md B.3; VV/II strings are [UNCONFIRMED] choices
documented in docs/scip-fake.md."""

UTM_30LX_CAPTURED = ScipIdentity(
    vendor="Hokuyo Automatic Co.,Ltd.",
    product="SOKUIKI Sensor TOP-URG UTM-30LX",
    firmware="P.1.05(17/Apr./2009)",
    protocol="SCIP 2.0",
    serial="00903971",
    pp_model="UTM-30LX(Hokuyo Automatic Co.,Ltd.)",
    ii_model="UTM-30LX(Hokuyo Automatic Co.,Ltd.)",
    ii_motor_speed="Initial(2400[rpm])<-Default setting by user",
    ii_mode_idle="CLASSIC",
    ii_mode_measuring="CLASSIC",
    ii_mode_streaming="CLASSIC",
    ii_mode_time_adjust="CLASSIC",
    ii_link_ethernet="USB Full Speed",
    ii_link_serial="USB Full Speed",
    ii_status="Sensor works well.",
)
"""The real UTM-30LX (USB, firmware P.1.05) of scip_captures.md A.1."""

IDENTITIES: dict[str, ScipIdentity] = {"utm-30lx-ew": UTM_30LX_EW, "utm-30lx": UTM_30LX_CAPTURED}
"""Presets by name (the CLI's ``--identity``)."""


def identity_of_scanner(name: str) -> ScipIdentity:
    """``UTM_30LX_EW`` with a serial of its own for the scene scanner ``name``: ``default``
    keeps ``H0123456``; any other name gets ``H`` and 7 digits from its CRC-32, the same in
    every fake cell that serves it (a scanner's calibration and its verify see one serial)."""
    if name == DEFAULT_SCANNER_NAME:
        return UTM_30LX_EW
    return replace(UTM_30LX_EW, serial=f"H{zlib.crc32(name.encode()) % 10_000_000:07d}")
