"""Typed views of the VV/PP/II replies and of stream statistics."""

from __future__ import annotations

from dataclasses import dataclass, field

from drivers.hokuyo.codec import parse_time_field
from lasercal_hw.errors import ConfigError, ProtocolError
from lasercal_hw.models import ScanGeometry, ScannerIdentity

HEALTHY_DIAGNOSTICS = ("Sensor works well.", "Stable 000 no error.", "sensor is working normally")
"""II STAT strings of a healthy URG/UTM-30LX, UTM-30LX-EW and UST (scip2.md 4.3, P-7)."""
II_KEYS = ("MODL", "LASR", "SCSP", "MESM", "SBPS", "TIME", "STAT")
"""Keys every II reply carries (scip2.md 4.3; the URG-04LX, UTM-30LX and UXM captures)."""


def _required(params: dict[str, str], key: str, command: str) -> str:
    if key not in params:
        raise ProtocolError(f"{command} reply lacks {key} (got keys {', '.join(sorted(params)) or 'none'})")
    return params[key]


def _integer(params: dict[str, str], key: str) -> int:
    text = _required(params, key, "PP")
    try:
        return int(text)
    except ValueError as exc:
        raise ProtocolError(f"PP {key} value {text!r} is not an integer") from exc


def parse_identity(version: dict[str, str], model: str) -> ScannerIdentity:
    """Identity from the VV reply and the PP ``MODL`` value."""
    return ScannerIdentity(
        vendor=_required(version, "VEND", "VV"),
        product=_required(version, "PROD", "VV"),
        firmware=_required(version, "FIRM", "VV"),
        protocol=_required(version, "PROT", "VV"),
        serial=_required(version, "SERI", "VV"),
        model=model,
    )


@dataclass(frozen=True)
class ScannerParameters:
    """The PP reply: range limits (mm), step layout and motor speed."""

    model: str
    min_range_mm: int
    max_range_mm: int
    steps_per_revolution: int
    first_step: int
    last_step: int
    front_step: int
    motor_speed_rpm: int
    raw: dict[str, str] = field(default_factory=dict)

    @property
    def scan_period_s(self) -> float:
        """One motor revolution (25 ms on a UTM-30LX-EW)."""
        return 60.0 / self.motor_speed_rpm

    def geometry(
        self, first_step: int | None = None, last_step: int | None = None, cluster: int = 1
    ) -> ScanGeometry:
        """Beam layout for a request; defaults to all measurable steps, cluster 1."""
        first = self.first_step if first_step is None else first_step
        last = self.last_step if last_step is None else last_step
        if not self.first_step <= first <= last <= self.last_step:
            raise ConfigError(
                f"steps {first}..{last} are outside the scanner's {self.first_step}..{self.last_step}"
            )
        if not 1 <= cluster <= 99:
            raise ConfigError(f"cluster {cluster} must be 1..99")
        return ScanGeometry(
            first_step=first,
            last_step=last,
            cluster=cluster,
            front_step=self.front_step,
            steps_per_revolution=self.steps_per_revolution,
            min_range_m=self.min_range_mm / 1000.0,
            max_range_m=self.max_range_mm / 1000.0,
            scan_period_s=self.scan_period_s,
        )


@dataclass(frozen=True)
class StepLayout:
    """The step numbers a scanner model's PP reply must carry (ARES, AMIN, AMAX, AFRT)."""

    steps_per_revolution: int
    first_step: int
    last_step: int
    front_step: int


KNOWN_LAYOUTS: dict[str, StepLayout] = {
    "UTM-30LX": StepLayout(1440, 0, 1080, 540),
    "URG-04LX": StepLayout(1024, 44, 725, 384),
}
"""Data sheet values by PP ``MODL`` prefix (UTM-30LX and UTM-30LX-EW share theirs;
scip_captures.md A.1, B.2, B.3)."""


def known_layout(model: str) -> tuple[str, StepLayout] | None:
    """The known layout whose model name ``model`` starts with (longest match), if any."""
    matches = [name for name in KNOWN_LAYOUTS if model.startswith(name)]
    if not matches:
        return None
    name = max(matches, key=len)
    return name, KNOWN_LAYOUTS[name]


def check_plausible(parameters: ScannerParameters) -> None:
    """``ProtocolError`` when the PP values cannot describe a real scanner, or differ from
    the known values of its model: a wrong front step turns every angle (issue 14)."""
    p = parameters
    if not (0 <= p.first_step <= p.front_step <= p.last_step < p.steps_per_revolution):
        raise ProtocolError(
            f"PP steps are impossible: AMIN {p.first_step} <= AFRT {p.front_step} <= AMAX {p.last_step} "
            f"< ARES {p.steps_per_revolution} does not hold; the reply is corrupted"
        )
    if not 0 <= p.min_range_mm < p.max_range_mm:
        raise ProtocolError(f"PP ranges are impossible: DMIN {p.min_range_mm} >= DMAX {p.max_range_mm}")
    known = known_layout(p.model)
    if known is None:
        return
    name, layout = known
    found = StepLayout(p.steps_per_revolution, p.first_step, p.last_step, p.front_step)
    keys = {"steps_per_revolution": "ARES", "first_step": "AMIN", "last_step": "AMAX", "front_step": "AFRT"}
    differ = [
        f"{key} {getattr(found, field_name)} (a {name} has {getattr(layout, field_name)})"
        for field_name, key in keys.items()
        if getattr(found, field_name) != getattr(layout, field_name)
    ]
    if differ:
        raise ProtocolError(
            f"PP of a {p.model} reports {', '.join(differ)}; every scan angle would be wrong, so the "
            "scanner is refused: check the link for corruption and that MODL names the real model"
        )


def parse_parameters(params: dict[str, str]) -> ScannerParameters:
    """Typed PP reply; a missing or non-numeric key, or implausible values, are a
    ``ProtocolError`` (``check_plausible``)."""
    parameters = ScannerParameters(
        model=_required(params, "MODL", "PP"),
        min_range_mm=_integer(params, "DMIN"),
        max_range_mm=_integer(params, "DMAX"),
        steps_per_revolution=_integer(params, "ARES"),
        first_step=_integer(params, "AMIN"),
        last_step=_integer(params, "AMAX"),
        front_step=_integer(params, "AFRT"),
        motor_speed_rpm=_integer(params, "SCAN"),
        raw=dict(params),
    )
    if parameters.motor_speed_rpm <= 0:
        raise ProtocolError(f"PP SCAN {parameters.motor_speed_rpm} rpm is impossible; the reply is corrupted")
    check_plausible(parameters)
    return parameters


@dataclass(frozen=True)
class ScannerStatus:
    """The II reply."""

    model: str
    laser_on: bool | None
    motor_speed: str
    measurement_mode: str
    link: str
    time_ms: int | None
    diagnostic: str
    raw: dict[str, str] = field(default_factory=dict)

    @property
    def healthy(self) -> bool:
        """True when STAT is one of the known healthy strings."""
        return self.diagnostic.strip() in HEALTHY_DIAGNOSTICS


def parse_status(params: dict[str, str]) -> ScannerStatus:
    """Typed II reply; TIME may be 6 hex digits or the 4-char encoding (P-6). Every key
    of scip2.md 4.3 must be there (a reply that lost a line is refused, not read as a
    blank status)."""
    for key in II_KEYS:
        _required(params, key, "II")
    laser = params["LASR"].strip().upper()
    return ScannerStatus(
        model=params["MODL"],
        laser_on=True if laser.startswith("ON") else False if laser.startswith("OFF") else None,
        motor_speed=params["SCSP"],
        measurement_mode=params["MESM"],
        link=params["SBPS"],
        time_ms=parse_time_field(params["TIME"]),
        diagnostic=params["STAT"],
        raw=dict(params),
    )


@dataclass(frozen=True)
class StreamGap:
    """Scans missed while the connection was re-established."""

    missed_scans: int
    duration_s: float
    reason: str


@dataclass(frozen=True)
class StreamStats:
    """Counters of the current stream."""

    received: int
    queue_overflows: int
    corrupted: int
    reconnects: int
    missed_in_gaps: int
    gaps: tuple[StreamGap, ...]
