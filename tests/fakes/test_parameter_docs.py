"""The scanner model's and the extraction's parameters and the scene file's keys as the docs
state them (issue 18: every parameter in docs/ with its value and source): docs/scanner-model.md's
table of ``[physics]`` and docs/extraction.md's scene listing are held to ``fakes/scene.py``,
docs/extraction.md's settings table to ``ExtractionSettings``."""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from pathlib import Path
from typing import Any, get_args

import pytest
from pydantic import BaseModel

from fakes.scanner_model.materials import MATERIALS
from fakes.scene import Material, NoiseSettings, PhysicsSettings, Scene, scene_from_mapping
from lasercal_hw.scan.extraction import ExtractionSettings

DOCS = Path(__file__).resolve().parents[2] / "docs"
#: The units a table writes a default in, and the factor to the code's unit (m, rad, s, a
#: fraction); degrees stay degrees unless the parameter's name says radians.
_UNIT_SCALE = {"": 1.0, "m": 1.0, "mm": 1e-3, "rad": 1.0, "s": 1.0, "°": 1.0, "%": 0.01}


def _section(text: str, heading: str) -> str:
    """The lines of ``text`` from ``heading`` to the next heading of the same or a higher
    level (a ``#`` in a fenced block is a comment, not a heading)."""
    level = len(heading.split(" ")[0])
    lines = text.splitlines()
    assert heading in lines, f"no heading {heading!r}"
    start = lines.index(heading)
    fenced = False
    for end in range(start + 1, len(lines)):
        fenced ^= lines[end].startswith("```")
        hashes = len(lines[end]) - len(lines[end].lstrip("#"))
        if not fenced and 0 < hashes <= level and lines[end][hashes:].startswith(" "):
            return "\n".join(lines[start:end])
    return "\n".join(lines[start:])


def _table_rows(section: str) -> list[list[str]]:
    """The cells of every table row in ``section`` (the header and rule left out)."""
    rows = [line.strip().strip("|").split("|") for line in section.splitlines() if line.startswith("| ")]
    return [[cell.strip() for cell in row] for row in rows[1:] if not set(row[0].strip()) <= set("- :")]


def documented_defaults(path: Path, heading: str) -> dict[str, str]:
    """``name -> default`` as the parameter table under ``heading`` in ``path`` writes it
    (a row may name several parameters, its defaults then in the same order)."""
    found: dict[str, str] = {}
    for row in _table_rows(_section(path.read_text(encoding="utf-8"), heading)):
        names = re.findall(r"`([a-z_0-9]+)`", row[0])
        if not names:
            continue
        values = [v.strip() for v in re.split(r",\s+(?![^(]*\))", row[1])]
        assert len(values) == len(names), f"{path.name}: {row[0]}: {len(values)} defaults, {len(names)} names"
        found.update(zip(names, values, strict=True))
    return found


def matches(written: str, default: Any, in_radians: bool = False) -> bool:
    """Whether a table's ``written`` default (a number with an optional unit, a word, a
    tuple) is the code's ``default`` (``in_radians``: a value in degrees is converted)."""
    if isinstance(default, tuple):
        return [float(v) for v in re.findall(r"[-+\d.e]+", written)] == pytest.approx(list(default))
    written = re.sub(r"\s*\(.*\)$", "", written)  # a remark after the value: "true (false until ...)"
    if isinstance(default, bool):
        return written == str(default).lower()
    if isinstance(default, str):
        return written == default
    match = re.fullmatch(r"([-+]?[\d.]+(?:e[-+]?\d+)?)\s*(mm|m|rad|s|°|%)?", written)
    if match is None:
        return False
    value = float(match[1]) * _UNIT_SCALE[match[2] or ""]
    if match[2] == "°" and in_radians:
        value = math.radians(value)
    return value == pytest.approx(float(default), rel=1e-9, abs=1e-12)


def test_every_physics_parameter_is_documented_with_its_default() -> None:
    table = documented_defaults(DOCS / "scanner-model.md", "## Parameters and their sources")
    missing = sorted(set(PhysicsSettings.model_fields) - set(table))
    assert not missing, f"docs/scanner-model.md's parameter table lacks {missing}"
    unknown = sorted(set(table) - set(PhysicsSettings.model_fields))
    assert not unknown, f"docs/scanner-model.md's parameter table names {unknown}, not in PhysicsSettings"
    defaults = PhysicsSettings()
    wrong = {
        name: (written, getattr(defaults, name))
        for name, written in table.items()
        if not matches(written, getattr(defaults, name))
    }
    assert not wrong, f"docs/scanner-model.md states defaults the code does not have: {wrong}"


def _scene_listing() -> str:
    """The TOML block of docs/extraction.md's "Scene files" section."""
    text = (DOCS / "extraction.md").read_text(encoding="utf-8")
    section = _section(text, "## Scene files (`fakes/scenes/default.toml`)")
    return section.split("```toml\n", 1)[1].split("\n```", 1)[0]


def _tables(model: type[BaseModel]) -> dict[str, type[BaseModel]]:
    """The scene's tables (``[rod]``, ``[[walls]]``, ...) and the model each is read into."""
    found = {}
    for name, field in model.model_fields.items():
        annotation = field.annotation
        inner = getattr(annotation, "__args__", (annotation,))[-1]
        if isinstance(inner, type) and issubclass(inner, BaseModel):
            found[name] = inner
    return found


def test_the_documented_scene_listing_is_a_scene_file_naming_every_key() -> None:
    text = _scene_listing()
    scene_from_mapping(tomllib.loads(text), "docs/extraction.md")  # spelled as the loader reads it
    words = set(re.findall(r"[a-z_0-9]+", text))
    missing = sorted(name for name in Scene.model_fields if name not in words)
    for table, model in _tables(Scene).items():
        if table != "physics":  # its every key: docs/scanner-model.md's table, tested above
            missing += [f"{table}.{name}" for name in model.model_fields if name not in words]
    assert not missing, f"docs/extraction.md's scene listing does not name {missing}"


#: Keys the listing sets to an example on purpose, each saying so in its comment.
_EXAMPLE_VALUES = {"faults", "posts", "physics"}


def test_the_documented_scene_listing_gives_the_defaults() -> None:
    data = tomllib.loads(_scene_listing())
    default = Scene()
    wrong = {}
    for table in _tables(Scene):
        if table in _EXAMPLE_VALUES or table not in data:
            continue
        listed = data[table][0] if isinstance(data[table], list) else data[table]
        expected = getattr(default, table)
        expected = expected[0] if isinstance(expected, list) else expected
        for key, value in listed.items():
            if value != getattr(expected, key):
                wrong[f"{table}.{key}"] = (value, getattr(expected, key))
    assert data["model"] == default.model
    assert not wrong, f"docs/extraction.md's scene listing (defaults, it says) differs from Scene(): {wrong}"


def test_every_extraction_setting_is_documented_with_its_default() -> None:
    table = documented_defaults(DOCS / "extraction.md", "### Settings (`ExtractionSettings`)")
    defaults = {field.name: field.default for field in dataclasses.fields(ExtractionSettings)}
    missing = sorted(set(defaults) - set(table))
    assert not missing, f"docs/extraction.md's settings table lacks {missing}"
    unknown = sorted(set(table) - set(defaults))
    assert not unknown, f"docs/extraction.md's settings table names {unknown}, not in ExtractionSettings"
    wrong = {
        name: (written, defaults[name])
        for name, written in table.items()
        if not matches(written, defaults[name], in_radians=name.endswith("_rad"))
    }
    assert not wrong, f"docs/extraction.md states settings the code does not have: {wrong}"


def test_every_material_is_documented_with_its_optics() -> None:
    section = _section((DOCS / "scanner-model.md").read_text(encoding="utf-8"), "## What a beam does")
    rows = {row[0].strip("`"): row[1:4] for row in _table_rows(section) if re.fullmatch(r"`[a-z_]+`", row[0])}
    assert sorted(rows) == sorted(MATERIALS) == sorted(get_args(Material))
    for name, optics in MATERIALS.items():
        diffuse, specular, retro = rows[name]
        written = [float(diffuse)]
        written += [0.0, optics.specular_width_rad] if specular == "-" else _lobe(specular)
        written += [0.0, optics.retro_width_rad] if retro == "-" else _lobe(retro)
        expected = [optics.diffuse, optics.specular, optics.specular_width_rad]
        expected += [optics.retro, optics.retro_width_rad]
        assert written == pytest.approx(expected), f"docs/scanner-model.md's row for {name}"


def _lobe(cell: str) -> list[float]:
    """A lobe as the materials table writes it, ``weight (width rad)``."""
    match = re.fullmatch(r"([\d.]+) \(([\d.]+) rad\)", cell)
    assert match, f"not a lobe: {cell!r}"
    return [float(match[1]), float(match[2])]


def test_every_noise_setting_of_the_ideal_model_is_documented_with_its_default() -> None:
    table = documented_defaults(DOCS / "extraction.md", "## The simulated world (`fakes/world.py`)")
    assert sorted(table) == sorted(NoiseSettings.model_fields), "docs/extraction.md's [noise] table"
    defaults = NoiseSettings()
    wrong = {name: (written, getattr(defaults, name)) for name, written in table.items()}
    wrong = {name: pair for name, pair in wrong.items() if not matches(*pair)}
    assert not wrong, f"docs/extraction.md states [noise] defaults the code does not have: {wrong}"
