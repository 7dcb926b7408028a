"""The import rule of docs/architecture.md, checked on every module's source.

Each folder is on a floor and imports only the ground, its own folder and folders on lower
floors, never a sibling on its own floor. Devices (``drivers/``, ``fakes/``) are imported by
the library only inside a function (the engine's connect and dry-run steps, the daemon's
probes), so importing the library never loads a device; the CLI's command modules may import
them at the top. ``fakes/`` speaks SCIP through the driver's pure codec
(``drivers/hokuyo/codec.py``), which itself imports only the ground.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("lasercal_hw", "drivers", "fakes", "trajectories")
GROUND = frozenset(
    {"lasercal_hw", "lasercal_hw.errors", "lasercal_hw.models", "lasercal_hw.geometry", "lasercal_hw.config",
     "lasercal_hw.ur_kinematics"}
)
#: Floor of each folder above the ground (the ground is floor 0).
FLOORS = {
    "lasercal_hw.calibration": 1, "lasercal_hw.scan": 1, "lasercal_hw.session": 1, "lasercal_hw.outputs": 1,
    "trajectories": 1,
    "lasercal_hw.run": 2,
    "lasercal_hw.verify": 3,
    "lasercal_hw.live": 4,
    "lasercal_hw.service": 5,
    "lasercal_hw.cli": 6,
}
DEVICES = frozenset({"drivers", "fakes"})
PURE_CODEC = "drivers.hokuyo.codec"


@dataclass(frozen=True)
class Import:
    """One ``import`` of one of our packages in one module."""

    module: str
    target: str
    line: int
    top_level: bool


def folder(module: str) -> str:
    """The unit the rule speaks of: a ground module, a ``lasercal_hw`` folder or a top package."""
    parts = module.split(".")
    if parts[0] != "lasercal_hw":
        return parts[0]
    return module if module in GROUND else ".".join(parts[:2])


def our_imports() -> list[Import]:
    """Every absolute import of our packages in our packages' sources."""
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
            tree = ast.parse(path.read_text(), str(path))
            top = {id(node) for node in tree.body}
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    targets = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    targets = [_imported_module(node.module, alias.name) for alias in node.names]
                else:
                    continue
                found += [
                    Import(module, target, node.lineno, id(node) in top)
                    for target in targets
                    if target.split(".")[0] in PACKAGES
                ]
    return found


def _imported_module(package: str, name: str) -> str:
    """``from package import name``: the submodule when ``name`` is one, else the package."""
    path = ROOT.joinpath(*package.split("."), name)
    return f"{package}.{name}" if path.with_suffix(".py").exists() or path.is_dir() else package


def violation(edge: Import) -> str | None:
    """Why ``edge`` breaks the rule, or None."""
    source, target = folder(edge.module), folder(edge.target)
    if source == target:
        return None
    if target in GROUND:
        return None
    if source in GROUND:
        return "the ground imports nothing else of ours"
    if source in DEVICES:
        if source == "fakes" and edge.target == PURE_CODEC:
            return None
        return f"{source}/ imports only the ground (and fakes/ the SCIP codec)"
    if target in DEVICES:
        if source == "lasercal_hw.cli" or not edge.top_level:
            return None
        return "devices are imported inside the function that needs them, not at module top"
    if FLOORS[target] >= FLOORS[source]:
        return f"{source} (floor {FLOORS[source]}) may not import {target} (floor {FLOORS[target]})"
    return None


def test_every_folder_is_on_a_floor() -> None:
    edges = our_imports()
    folders = {folder(edge.module) for edge in edges} | {folder(edge.target) for edge in edges}
    assert folders - GROUND - DEVICES - set(FLOORS) == set()


def test_no_import_breaks_the_rule() -> None:
    broken = [
        f"{edge.module}:{edge.line} imports {edge.target}: {why}"
        for edge in our_imports()
        if (why := violation(edge)) is not None
    ]
    assert broken == []


@pytest.mark.parametrize(
    ("module", "target", "top_level", "broken"),
    [
        ("lasercal_hw.scan.extraction", "lasercal_hw.calibration.model", True, True),  # sibling
        ("lasercal_hw.run.engine", "lasercal_hw.verify.procedure", True, True),  # upward
        ("lasercal_hw.run.engine", "fakes.cell", True, True),  # a device at module top
        ("lasercal_hw.run.engine", "fakes.cell", False, False),  # ... inside the dry-run step
        ("fakes.scip_server", "drivers.hokuyo.client", True, True),  # not the pure codec
        ("fakes.scip_server", "drivers.hokuyo.codec", True, False),
        ("lasercal_hw.config", "lasercal_hw.scan.average", True, True),  # the ground
        ("lasercal_hw.cli.fake", "fakes.cell", True, False),
    ],
)
def test_the_rule_catches_what_it_should(module: str, target: str, top_level: bool, broken: bool) -> None:
    assert (violation(Import(module, target, 1, top_level)) is not None) == broken


def test_the_pure_codec_imports_only_the_ground() -> None:
    codec = [edge for edge in our_imports() if edge.module == PURE_CODEC]
    assert all(folder(edge.target) in GROUND for edge in codec)




def _code_strings(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every string constant of a module that is not a docstring."""
    tree = ast.parse(path.read_text(), str(path))
    docstrings = {id(node.value) for node in ast.walk(tree) if isinstance(node, ast.Expr)}
    return [
        (node.lineno, node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings
    ]


def _modules_below(front_ends: set[str]) -> list[Path]:
    return [
        path
        for package in PACKAGES
        for path in sorted((ROOT / package).rglob("*.py"))
        if folder(".".join(path.relative_to(ROOT).with_suffix("").parts)) not in front_ends
    ]


def test_the_library_names_actions_not_command_line_flags() -> None:
    """Below the front ends a message says "resume this run from its recording"; the CLI adds
    ``--resume`` and the daemon ``POST /v1/jobs/{id}/resume``."""
    flagged = [
        f"{path.relative_to(ROOT)}:{line}"
        for path in _modules_below({"lasercal_hw.cli", "lasercal_hw.service"})
        for line, text in _code_strings(path)
        if "--resume" in text
    ]
    assert flagged == []


def test_nothing_below_the_cli_starts_the_cli() -> None:
    """No module below the CLI names it in code (e.g. ``python -m lasercal_hw.cli.main`` for a child)."""
    named = [
        f"{path.relative_to(ROOT)}:{line}"
        for path in _modules_below({"lasercal_hw.cli"})
        for line, text in _code_strings(path)
        if "lasercal_hw.cli" in text
    ]
    assert named == []
