"""An environment in which the transport libraries cannot be imported (no tests here): a
``sitecustomize`` on ``PYTHONPATH`` puts a meta-path finder first that raises ImportError for
pymavlink, zenoh, can and dronecan and their submodules, in every Python process started with
that environment (Dask workers too)."""

from __future__ import annotations

import os
from pathlib import Path

TRANSPORTS = ("pymavlink", "zenoh", "can", "dronecan")

REFUSER = f"""
import sys

class Refuse:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {TRANSPORTS!r}:
            raise ImportError(f"{{name}} is refused in this test")
        return None

sys.meta_path.insert(0, Refuse())
"""


def env_without_transports(folder: Path) -> dict[str, str]:
    """``os.environ`` with ``folder`` (created, holding the sitecustomize) first on PYTHONPATH."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sitecustomize.py").write_text(REFUSER)
    path = os.pathsep.join(p for p in (str(folder), os.environ.get("PYTHONPATH", "")) if p)
    return {**os.environ, "PYTHONPATH": path}
