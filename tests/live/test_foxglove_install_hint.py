"""Without the Foxglove SDK, `--foxglove` says how to install it, with a command that works from
lasercal's checkout (lasercal is installed from it, `pip install -e .`, not from an index)."""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path

import pytest

from lasercal_hw.errors import ConfigError
from lasercal_hw.live.foxglove import FoxgloveLiveView

PYPROJECT = Path(__file__).resolve().parents[2] / "pyproject.toml"


def test_without_the_sdk_the_live_view_names_the_checkouts_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "foxglove", None)  # `import foxglove` raises ImportError
    with pytest.raises(ConfigError) as caught:
        FoxgloveLiveView(port=0)
    command = re.search(r"\.venv/bin/pip install -e '\.\[(\w+)\]'", str(caught.value))
    assert command is not None, str(caught.value)
    extras = tomllib.loads(PYPROJECT.read_text(encoding="utf-8"))["project"]["optional-dependencies"]
    assert any(requirement.startswith("foxglove-sdk") for requirement in extras[command[1]])
