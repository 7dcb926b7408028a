"""The loopback guard: with ``LASERCAL_LOOPBACK_ONLY`` set in the environment (the test suite
sets it, a dry-run daemon sets it for itself and its children), the drivers open network
connections to IPv4 loopback addresses (127.0.0.0/8) only, and refuse any other before a
packet leaves. Its value says who asked, for the message."""

from __future__ import annotations

import ipaddress
import os

from lasercal_hw.errors import ConfigError

LOOPBACK_ONLY_ENV = "LASERCAL_LOOPBACK_ONLY"


def check_host(host: str, what: str) -> None:
    """Refuse (ConfigError) a connection to ``host`` for ``what`` when the guard is on and
    ``host`` is not an IPv4 loopback address; a host name is refused too (it may resolve
    anywhere)."""
    why = os.environ.get(LOOPBACK_ONLY_ENV)
    if not why:
        return
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        address = None
    if address is None or address.version != 4 or not address.is_loopback:
        raise ConfigError(
            f"{what} at {host} refused: this process connects to loopback addresses (127.0.0.X) "
            f"only ({LOOPBACK_ONLY_ENV}: {why})"
        )
