"""The core imports none of the transport libraries (STYLE.md, Layers)."""

from __future__ import annotations

import json
import subprocess
import sys

CORE = [
    "core",
    "allocator",
    "estimator",
    "excitation",
    "geometry",
    "plants",
    "qp",
    "scenario",
    "report",
    "controllers",
    "messages",
]
FORBIDDEN = ("can", "zenoh", "pymavlink", "dronecan", "bridges")


def test_core_imports_no_transport() -> None:
    code = (
        "import json, sys\n"
        + "".join(f"import ftcap_hil.{name}\n" for name in CORE)
        + "print(json.dumps(sorted(sys.modules)))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    modules = json.loads(out.stdout)
    assert "ftcap_hil.core.cycle" in modules and "numpy" in modules  # the probe did run
    leaked = [m for m in modules if m.split(".")[0] in FORBIDDEN]
    assert leaked == []
