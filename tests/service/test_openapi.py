"""The daemon's OpenAPI document is pinned: a change to the HTTP API (a path, a body field,
a parameter, a doc string) shows up here and is made on purpose.

After a deliberate change, regenerate the snapshot with::

    .venv/bin/python -m tests.service.test_openapi > tests/data/openapi.json
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

from lasercal_hw.service.app import create_app
from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon

SNAPSHOT = Path(__file__).parents[1] / "data" / "openapi.json"


def openapi_text(data_dir: Path) -> str:
    """The OpenAPI document of a daemon on ``data_dir``, as the snapshot stores it."""
    daemon = Daemon(load_daemon_config(None, {"data_dir": data_dir}))
    try:
        return json.dumps(create_app(daemon).openapi(), indent=1, sort_keys=True) + "\n"
    finally:
        daemon.store.close()


def test_openapi_document_matches_the_snapshot(tmp_path: Path) -> None:
    assert openapi_text(tmp_path / "data") == SNAPSHOT.read_text(encoding="utf-8"), (
        "the HTTP API changed; if on purpose, regenerate the snapshot (see the module docstring)"
    )


if __name__ == "__main__":
    with tempfile.TemporaryDirectory() as folder:
        sys.stdout.write(openapi_text(Path(folder) / "data"))
