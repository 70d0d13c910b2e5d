"""Imports only go down the layers, and the folders are the layers (STYLE.md, Layers).

Every product module is read with ``ast`` (imports inside functions count too); its layer is
the folder it lives in, so no list of modules has to be kept here::

    apps     ftcap_hil/apps, ftcap_hil/__main__.py   composition roots, one per command
    config   ftcap_hil/config                        files -> typed settings
    runtime  ftcap_hil/runtime                       loops, processes, the daemon's parts
    report   ftcap_hil/report                        records, results, plots
    bridges  bridges/                                transport adapters
    sim      sim/                                    the vessel's truth model
    ports    ftcap_hil/ports                         mailboxes and queues
    core     ftcap_hil/core                          the maths and its types

A module may import its own layer or one below; ``bridges`` and ``sim`` do not import each
other; nothing imports ``apps``.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RANK = {"core": 0, "ports": 1, "bridges": 2, "sim": 2, "report": 3, "runtime": 4, "config": 5}
RANK["apps"] = 6
TRANSPORT = {"can", "zenoh", "pymavlink", "dronecan", "serial"}
# What the pure layers may import besides the standard library's pure parts.
CORE_THIRD_PARTY = {"numpy", "qpsolvers", "proxsuite", "daqp"}
IMPURE_STDLIB = {
    "socket", "threading", "time", "subprocess", "select", "selectors", "signal", "asyncio",
    "multiprocessing", "logging", "os", "shutil", "tempfile", "http", "urllib",
}  # fmt: skip
SIM_FORBIDDEN_CORE = {"allocation", "estimation", "cycle"}


def layer_of(path: Path) -> str:
    rel = path.relative_to(ROOT).parts
    if rel[0] in ("bridges", "sim"):
        return rel[0]
    if rel[1] == "__main__.py":
        return "apps"
    return "core" if rel[1] == "__init__.py" else rel[1]  # the package root holds no code


def module_layer(name: str) -> str | None:
    """Layer of an imported module of ours, None for anything else."""
    parts = name.split(".")
    if parts[0] in ("bridges", "sim"):
        return parts[0]
    if parts[0] == "ftcap_hil" and len(parts) > 1 and parts[1] in RANK:
        return parts[1]
    return None


def product_files() -> list[Path]:
    files = [*(ROOT / "ftcap_hil").rglob("*.py"), *(ROOT / "bridges").rglob("*.py")]
    files += (ROOT / "sim").rglob("*.py")
    return sorted(p for p in files if "data" not in p.relative_to(ROOT).parts)


def imports_of(path: Path) -> list[str]:
    names = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
            names += [f"{node.module}.{a.name}" for a in node.names]
    return names


def violations(path: Path) -> list[str]:
    layer = layer_of(path)
    out = []
    for name in imports_of(path):
        top = name.split(".")[0]
        other = module_layer(name)
        if other is not None and other != layer:
            if other == "apps" or RANK[other] > RANK[layer] or {layer, other} == {"bridges", "sim"}:
                out.append(f"{layer} imports {other}: {name}")
        if layer in ("core", "sim") and top in TRANSPORT | {"matplotlib"} | IMPURE_STDLIB:
            out.append(f"{layer} imports {name}")
        if layer in ("core", "sim") and other is None and "." not in name:
            is_ours = top in ("ftcap_hil", "bridges", "sim")
            if not is_ours and top not in CORE_THIRD_PARTY and top not in sys.stdlib_module_names:
                out.append(f"{layer} imports third-party {name}")
        if layer == "sim" and name.startswith("ftcap_hil.core."):
            if name.split(".")[2] in SIM_FORBIDDEN_CORE:
                out.append(f"sim imports the allocator's machinery: {name}")
        if top == "matplotlib" and layer != "report":
            out.append(f"{layer} imports matplotlib (report only)")
    return out


@pytest.mark.parametrize("path", product_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_only_go_down(path: Path) -> None:
    assert violations(path) == []


def test_the_checker_sees_a_violation(tmp_path: Path) -> None:
    """The rule itself can fail: a core module importing a bridge is caught."""
    bad = ROOT / "ftcap_hil" / "core" / "_probe_layering.py"
    bad.write_text("import socket\nfrom bridges.can_io.bus import open_can_bus\n")
    try:
        found = violations(bad)
    finally:
        bad.unlink()
    assert any("core imports bridges" in v for v in found)
    assert any("core imports socket" in v for v in found)


def test_every_product_folder_is_a_known_layer() -> None:
    assert {layer_of(p) for p in product_files()} <= set(RANK)


def test_importing_the_core_loads_no_transport_or_plotting() -> None:
    """At run time too: the whole core imported, nothing of the transports comes with it."""
    core = sorted(
        ".".join(p.relative_to(ROOT).with_suffix("").parts)
        for p in (ROOT / "ftcap_hil" / "core").rglob("*.py")
        if p.stem != "__init__"
    )
    code = "".join(f"import {m}\n" for m in core)
    code += "import json, sys\nprint(json.dumps(sorted(sys.modules)))\n"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    modules = json.loads(out.stdout)
    assert "ftcap_hil.core.cycle" in modules and "numpy" in modules  # the probe did run
    leaked = [m for m in modules if m.split(".")[0] in TRANSPORT | {"matplotlib", "bridges"}]
    assert leaked == []
