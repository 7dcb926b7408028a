"""The bearer token that guards everything which moves the arm or changes the active
calibration: a file the daemon creates on first start (mode 0600), compared in constant time."""

from __future__ import annotations

import hmac
import os
import secrets
from pathlib import Path

from lasercal_hw.errors import ConfigError
from lasercal_hw.service.errors import ForbiddenError, UnauthenticatedError

TOKEN_ENV = "LASERCAL_TOKEN"


def ensure_token(path: Path) -> str:
    """The token in ``path``; a new random one (written with mode 0600) when the file is missing.

    An existing file readable by group or others is refused: anyone who can read it can move the arm.
    """
    try:
        descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        return _existing_token(path)
    except OSError as exc:
        raise ConfigError(f"cannot create the token file {path}: {exc.strerror or exc}") from None
    token = secrets.token_urlsafe(32)
    with os.fdopen(descriptor, "w", encoding="utf-8") as handle:
        handle.write(token + "\n")
    return token


def _existing_token(path: Path) -> str:
    mode = path.stat().st_mode & 0o777
    if mode & 0o077:
        raise ConfigError(f"token file {path} has mode {mode:o}; run 'chmod 600 {path}'")
    token = path.read_text(encoding="utf-8").strip()
    if len(token) < 16:
        raise ConfigError(f"token file {path} holds no token of 16+ characters; delete it to get a new one")
    return token


def check_bearer(authorization: str | None, token: str) -> None:
    """UnauthenticatedError without a bearer token, ForbiddenError with a wrong one."""
    if not authorization:
        raise UnauthenticatedError(
            "this request needs 'Authorization: Bearer <token>' (the token is "
            "in the daemon's token file, see docs/daemon.md)",
        )
    scheme, _, presented = authorization.partition(" ")
    if scheme.lower() != "bearer" or not presented.strip():
        raise UnauthenticatedError("the Authorization header must be 'Bearer <token>'")
    if not hmac.compare_digest(presented.strip().encode(), token.encode()):
        raise ForbiddenError("wrong token; read it from the daemon's token file")
