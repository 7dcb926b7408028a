"""The daemon configuration (``daemon.toml``): where the devices are, the default job, the
data folder, where to listen. Every field has a default; unknown keys are refused."""

from __future__ import annotations

import ipaddress
import os
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from lasercal_hw.config import check_scanner_url, read_toml
from lasercal_hw.errors import ConfigError

DEFAULT_PORT = 8766  # beside Foxglove's 8765, which the live view may use
DEFAULT_LISTEN = f"127.0.0.1:{DEFAULT_PORT}"


def default_data_dir() -> Path:
    """``$XDG_STATE_HOME/lasercal`` (``~/.local/state/lasercal``): per user, survives reboots."""
    state_home = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(state_home) / "lasercal"


class DaemonScanner(BaseModel):
    """One of the cell's scanners (``[scanners.NAME]``): where a cell job's scanner of that
    name is (the job's ``scanners.NAME.url`` otherwise)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    url: str

    _known_scheme = field_validator("url")(check_scanner_url)


class DaemonConfig(BaseModel):
    """What ``lasercal serve`` needs besides the job itself."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    listen: str = DEFAULT_LISTEN
    data_dir: Path = Field(default_factory=default_data_dir)
    robot_host: str | None = None
    scanner_url: str | None = None
    scanners: dict[str, DaemonScanner] = Field(
        default_factory=dict, description="a cell's scanners by name, for cell jobs (docs/cell.md)"
    )
    default_job: Path | None = None
    dry_run_scene: Path | None = Field(
        None, description="dry run only: the fake cell's scene file (its [scanners.NAME] are the cell's "
        "scanners), and the scene of a dry-run job that gives none",
    )
    token_file: Path | None = Field(None, description="default: <data_dir>/token")
    status_poll_s: float = Field(2.0, gt=0.0, le=60.0)
    dry_run: bool = False
    allowed_hosts: tuple[str, ...] = Field(
        (), description="host names the daemon answers to besides its listen address and localhost"
    )
    log_format: Literal["text", "json"] = Field(
        "text", description="the daemon's log on stderr: text lines for a person, or JSON lines"
    )

    @field_validator("listen")
    @classmethod
    def _host_port(cls, listen: str) -> str:
        listen_address(listen)
        return listen

    @property
    def token_path(self) -> Path:
        """Where the bearer token lives."""
        return self.token_file or self.data_dir / "token"

    @property
    def loopback_only(self) -> bool:
        """True when the daemon listens on a loopback address only."""
        host, _ = listen_address(self.listen)
        if host == "localhost":
            return True
        try:
            return ipaddress.ip_address(host).is_loopback
        except ValueError:
            return False


def listen_address(listen: str) -> tuple[str, int]:
    """``HOST:PORT`` split and checked (port 0 picks a free port)."""
    host, sep, port_text = listen.rpartition(":")
    if not sep or not host or not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise ValueError(f"{listen!r} is not HOST:PORT (e.g. {DEFAULT_LISTEN})")
    return host.strip("[]"), int(port_text)


def load_daemon_config(path: Path | None, overrides: dict[str, Any]) -> DaemonConfig:
    """Read ``daemon.toml`` (``None``: defaults) and apply the command-line overrides."""
    data: dict[str, Any] = {}
    source = "daemon configuration"
    if path is not None:
        source = str(path)
        data = read_toml(path, "daemon configuration")
    data |= {key: value for key, value in overrides.items() if value is not None}
    try:
        config = DaemonConfig.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or '(top level)'}: "
            + ("unknown field" if e["type"] == "extra_forbidden" else e["msg"])
            for e in exc.errors()
        )
        raise ConfigError(f"{source}: {problems} (see docs/daemon.md)") from None
    if path is not None:  # files named in daemon.toml are relative to it
        relative = {key: (Path(path).parent / value).resolve() for key in ("default_job", "dry_run_scene")
                    if (value := getattr(config, key)) is not None and not value.is_absolute()}
        config = config.model_copy(update=relative)
    if config.dry_run_scene is not None and not config.dry_run_scene.is_file():
        raise ConfigError(f"{source}: dry_run_scene: no scene file {config.dry_run_scene} (see docs/cell.md)")
    return config
