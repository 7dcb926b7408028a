"""What every request passes before any route: a Host header that names this daemon (a
page that rebinds its own DNS name to 127.0.0.1 sends its own name and is refused) and a
body no larger than ``MAX_BODY_BYTES`` (413 naming the limit)."""

from __future__ import annotations

import ipaddress
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

from lasercal_hw.service.routes.problems import problem

MAX_BODY_BYTES = 256 * 1024
"""The largest request body taken (a job with a few hundred waypoints is a few kB)."""

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]


def host_name(header: str) -> str:
    """The host of a Host header, without port or IPv6 brackets, lower case."""
    header = header.strip().lower()
    if header.startswith("["):
        return header[1 : header.find("]")] if "]" in header else header
    name = header.rpartition(":")[0] if header.count(":") == 1 else header
    return name.rstrip(".")


def allowed_host(name: str, listen_host: str, names: tuple[str, ...]) -> bool:
    """An IP literal (no DNS name a rebinding page could own), ``localhost``, the listen
    host or a configured name."""
    try:
        ipaddress.ip_address(name)
        return True
    except ValueError:
        return name in ("localhost", listen_host.lower(), *(n.lower() for n in names))


class RequestGuard:
    """ASGI middleware: Host check and body size limit, answered as problems."""

    def __init__(self, app: ASGIApp, listen_host: str, names: tuple[str, ...] = ()) -> None:
        self.app = app
        self.listen_host = listen_host
        self.names = names

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {key.lower(): value for key, value in scope["headers"]}
        host = host_name(headers.get(b"host", b"").decode("latin-1"))
        if not allowed_host(host, self.listen_host, self.names):
            answer = problem(
                400,
                "host_not_allowed",
                f"this daemon answers to its listen address, localhost or the names in allowed_hosts, "
                f"not {host[:100]!r}; add the name to allowed_hosts in daemon.toml if it is yours",
                {"field": "Host"},
            )
            await answer(scope, receive, send)
            return
        length = headers.get(b"content-length")
        too_large = problem(
            413,
            "payload_too_large",
            f"the request body is larger than {MAX_BODY_BYTES} bytes, the most this daemon takes",
            {"limit_bytes": MAX_BODY_BYTES},
        )
        if length is not None:
            if not length.isdigit() or int(length) > MAX_BODY_BYTES:
                await too_large(scope, receive, send)
                return
            await self.app(scope, receive, send)
            return
        body, more = [], True
        while more:  # a body without a length (chunked) is read up to the limit first
            message = await receive()
            if message["type"] != "http.request":
                return
            body.append(message.get("body", b""))
            more = bool(message.get("more_body"))
            if sum(len(part) for part in body) > MAX_BODY_BYTES:
                await too_large(scope, receive, send)
                return
        replayed = False

        async def replay() -> Message:
            nonlocal replayed
            if replayed:
                return await receive()
            replayed = True
            return {"type": "http.request", "body": b"".join(body), "more_body": False}

        await self.app(scope, replay, send)
