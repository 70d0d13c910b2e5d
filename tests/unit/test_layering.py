"""Imports only go down the layers, and the folders are the layers (STYLE.md, Layers).

The checker is tests/support/layering.py; here it runs on every product module, and on small
fake trees in a temporary folder, one per hole it once had, so that none reopens.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.layering import ORDER, RANK, TRANSPORT_HOME, layer_of, product_files, violations

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("path", product_files(ROOT), ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_only_go_down(path: Path) -> None:
    assert violations(path, ROOT) == []


def test_every_product_folder_is_a_known_layer() -> None:
    assert {layer_of(p, ROOT) for p in product_files(ROOT)} <= set(RANK)


def test_the_order_is_the_one_the_readme_states() -> None:
    assert RANK == {
        "core": 0, "ports": 1, "bridges": 2, "sim": 2, "config": 3, "report": 4, "runtime": 5,
        "apps": 6,
    }  # fmt: skip
    assert f"Layers, lowest first: {ORDER}." in " ".join((ROOT / "README.md").read_text().split())


def found_in(root: Path, files: dict[str, str]) -> dict[str, list[str]]:
    """Write a fake tree of ``files`` (path -> source) under ``root``; each file's violations."""
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return {
        str(p.relative_to(root)): violations(p, root)
        for p in product_files(root)
        if str(p.relative_to(root)) in files
    }


def test_the_order_puts_config_below_report_and_runtime(tmp_path: Path) -> None:
    found = found_in(
        tmp_path,
        {
            "ftcap_hil/config/a.py": "from ftcap_hil.runtime.loop import X\n"
            "import ftcap_hil.report.b\n",
            "ftcap_hil/report/a.py": "from ftcap_hil.runtime import loop\n"
            "from ftcap_hil.config import b\n",
            "ftcap_hil/runtime/a.py": "from ftcap_hil.report import b\n"
            "from ftcap_hil.config import c\n",
            "ftcap_hil/core/a.py": "from ftcap_hil.apps import cli\nimport ftcap_hil.ports.m\n",
        },
    )  # fmt: skip
    assert found == {
        "ftcap_hil/config/a.py": [
            "1: config imports runtime: ftcap_hil.runtime.loop.X",
            "2: config imports report: ftcap_hil.report.b",
        ],
        "ftcap_hil/report/a.py": ["1: report imports runtime: ftcap_hil.runtime.loop"],
        "ftcap_hil/runtime/a.py": [],
        "ftcap_hil/core/a.py": [
            "1: core imports apps: ftcap_hil.apps.cli",
            "2: core imports ports: ftcap_hil.ports.m",
        ],
    }


def test_runtime_gets_the_transports_handed_in(tmp_path: Path) -> None:
    found = found_in(
        tmp_path,
        {
            "ftcap_hil/runtime/a.py": "from bridges.can_io.bus import open_can_bus\n",
            "ftcap_hil/apps/a.py": "from bridges.can_io.bus import b\n"
            "from ftcap_hil.runtime import a\n",
        },
    )  # fmt: skip
    assert found["ftcap_hil/runtime/a.py"] == [
        "1: runtime imports bridges (apps wire them): bridges.can_io.bus.open_can_bus"
    ]
    assert found["ftcap_hil/apps/a.py"] == []


def test_a_relative_import_is_resolved(tmp_path: Path) -> None:
    found = found_in(
        tmp_path,
        {
            "ftcap_hil/core/a.py": "from ..runtime import loop\n"
            "from . import b\nfrom .b import c\n",
            "ftcap_hil/core/sub/__init__.py": "from ...runtime import x\nfrom .. import a\n",
            "ftcap_hil/runtime/__init__.py": "from ..report import r\nfrom .loop import y\n",
        },
    )  # fmt: skip
    assert found == {
        "ftcap_hil/core/a.py": ["1: core imports runtime: ftcap_hil.runtime.loop"],
        "ftcap_hil/core/sub/__init__.py": ["1: core imports runtime: ftcap_hil.runtime.x"],
        "ftcap_hil/runtime/__init__.py": [],
    }


def test_a_literal_importlib_call_is_an_import(tmp_path: Path) -> None:
    source = (
        "import importlib\nfrom importlib import import_module\n"
        "importlib.import_module('bridges.can_io.bus')\n"
        "m = __import__('ftcap_hil.runtime.loop')\n"
        "import_module('.daemon', package='ftcap_hil.runtime')\n"
        "import_module('..report', 'ftcap_hil.core')\n"
        "importlib.import_module('.cycle', package='ftcap_hil.core')\n"
        "importlib.import_module(NAME)\n"
    )
    found = found_in(tmp_path, {"ftcap_hil/core/a.py": source})
    assert found["ftcap_hil/core/a.py"] == [
        "3: core imports bridges: bridges.can_io.bus",
        "4: core imports runtime: ftcap_hil.runtime.loop",
        "5: core imports runtime: ftcap_hil.runtime.daemon",
        "6: core imports report: ftcap_hil.report",
    ]


def test_a_dotted_third_party_import_is_checked(tmp_path: Path) -> None:
    source = (
        "from scipy.linalg import expm\nimport numpy.linalg\nimport collections.abc\n"
        "from pandas.io import json\nimport sklearn.linear_model\nfrom os.path import join\n"
    )
    found = found_in(tmp_path, {"ftcap_hil/core/a.py": source})
    assert found["ftcap_hil/core/a.py"] == [
        "4: core imports third-party pandas.io.json",
        "5: core imports third-party sklearn.linear_model",
        "6: core imports os.path.join (impure standard library)",
    ]


def test_sim_imports_only_what_is_allowed(tmp_path: Path) -> None:
    source = (
        "import math\nimport numpy as np\nfrom ftcap_hil.core.messages import FloatArray\n"
        "from ftcap_hil.core.models.plants import wrap_angle\nfrom ftcap_hil.core import faults\n"
        "from sim.waves import jonswap\n"
        "import json\nfrom scipy.linalg import expm\nfrom ftcap_hil.core import cycle\n"
        "from ftcap_hil.core.allocation.qp import Solver\nfrom ftcap_hil.ports import mailbox\n"
        "from ftcap_hil.core.messagesx import Y\n"
    )
    found = found_in(tmp_path, {"sim/a.py": source})
    assert found["sim/a.py"] == [
        "7: sim imports json, not in SIM_MAY_IMPORT",
        "8: sim imports scipy.linalg.expm, not in SIM_MAY_IMPORT",
        "9: sim imports ftcap_hil.core.cycle, not in SIM_MAY_IMPORT",
        "10: sim imports ftcap_hil.core.allocation.qp.Solver, not in SIM_MAY_IMPORT",
        "11: sim imports ftcap_hil.ports.mailbox, not in SIM_MAY_IMPORT",
        "12: sim imports ftcap_hil.core.messagesx.Y, not in SIM_MAY_IMPORT",
    ]


def test_each_transport_library_stays_in_its_bridge_folder(tmp_path: Path) -> None:
    found = found_in(
        tmp_path,
        {
            "bridges/can_io/a.py": "import can\nimport dronecan.dsdl\nimport zenoh\n",
            "bridges/zenoh_io/a.py": "import zenoh\nfrom pymavlink import mavutil\n",
            "bridges/mavlink/a.py": "from pymavlink.dialects.v20 import common\n"
            "from bridges.can_io import a\n",
            "ftcap_hil/apps/a.py": "import can\n",
            "ftcap_hil/runtime/a.py": "from zenoh import Config\n",
        },
    )
    assert found == {
        "bridges/can_io/a.py": [
            "3: bridges/can_io imports zenoh (only bridges/zenoh_io may): zenoh"
        ],
        "bridges/zenoh_io/a.py": [
            "2: bridges/zenoh_io imports pymavlink (only bridges/mavlink may): pymavlink.mavutil"
        ],
        "bridges/mavlink/a.py": [
            "2: bridges/mavlink imports another bridge folder: bridges.can_io.a"
        ],
        "ftcap_hil/apps/a.py": ["1: ftcap_hil/apps imports can (only bridges/can_io may): can"],
        "ftcap_hil/runtime/a.py": [
            "1: ftcap_hil/runtime imports zenoh (only bridges/zenoh_io may): zenoh.Config"
        ],
    }
    assert set(TRANSPORT_HOME) >= {"pymavlink", "zenoh", "can", "dronecan"}


def test_matplotlib_is_for_report_only(tmp_path: Path) -> None:
    found = found_in(
        tmp_path,
        {
            "ftcap_hil/report/a.py": "import matplotlib.pyplot\n",
            "ftcap_hil/runtime/a.py": "import matplotlib\n",
        },
    )
    assert found == {
        "ftcap_hil/report/a.py": [],
        "ftcap_hil/runtime/a.py": ["1: runtime imports matplotlib (report only): matplotlib"],
    }


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
    leaked = [m for m in modules if m.split(".")[0] in {*TRANSPORT_HOME, "matplotlib", "bridges"}]
    assert leaked == []
