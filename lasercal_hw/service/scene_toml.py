"""A fake-cell scene sent as JSON (``"scene": {...}`` in a dry-run job) checked and
written as the TOML file the fake cell reads."""

from __future__ import annotations

from typing import Any

from fakes.scene import scene_from_mapping
from lasercal_hw.errors import ConfigError
from lasercal_hw.service.problems import ApiError


def scene_toml(scene: dict[str, Any]) -> str:
    """TOML text for ``scene``, validated as a scene: a bad one is a 422 naming the field."""
    try:
        return scene_from_mapping(scene, "scene").to_toml()
    except ConfigError as exc:
        raise ApiError(422, "invalid_request", str(exc).replace("\n", " "), {"field": "scene"}) from None
