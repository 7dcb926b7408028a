"""A fake-cell scene sent as JSON (``"scene": {...}`` in a dry-run job) checked and
written as the TOML file the fake cell reads."""

from __future__ import annotations

import json
from typing import Any

from lasercal_hw.errors import ConfigError
from lasercal_hw.service.problems import ApiError


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a valid TOML basic string
    if isinstance(value, list) and not any(isinstance(v, dict) for v in value):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    raise ApiError(
        422, "invalid_request", f"scene value {value!r} cannot be written as TOML", {"field": "scene"}
    )


def scene_toml(scene: dict[str, Any]) -> str:
    """TOML text for ``scene`` (tables, arrays of tables, scalars, lists), validated as a
    scene: a bad one is a 422 naming the field."""
    lines: list[str] = []
    tables = {k: v for k, v in scene.items() if isinstance(v, dict)}
    arrays = {
        k: v for k, v in scene.items() if isinstance(v, list) and v and all(isinstance(i, dict) for i in v)
    }
    for key, value in scene.items():
        if key not in tables and key not in arrays:
            lines.append(f"{key} = {_value(value)}")
    for name, table in tables.items():
        lines += ["", f"[{name}]", *(f"{k} = {_value(v)}" for k, v in table.items())]
    for name, items in arrays.items():
        for item in items:
            lines += ["", f"[[{name}]]", *(f"{k} = {_value(v)}" for k, v in item.items())]
    text = "\n".join(lines) + "\n"
    from fakes.scene import parse_scene

    try:
        parse_scene(text, "scene")
    except ConfigError as exc:
        raise ApiError(422, "invalid_request", str(exc).replace("\n", " "), {"field": "scene"}) from None
    return text
