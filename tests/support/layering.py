"""The layering checker (no tests here; tests/unit/test_layering.py runs it on the tree and on
small fake trees).

Every product module under a root (``ftcap_hil/``, ``bridges/``, ``sim/``) is read with ``ast``;
an import is an ``import``/``from`` statement anywhere in the module (in functions too, relative
ones resolved against the module's package) or an ``importlib.import_module``/``__import__``
call with a literal name. A module's layer is the folder it lives in (ORDER, lowest first)::

    core     ftcap_hil/core         the maths and its types
    ports    ftcap_hil/ports        mailboxes, stamped values
    bridges  bridges/               transport adapters, one library per folder
    sim      sim/                   the vessel's truth model
    config   ftcap_hil/config       files -> typed settings
    report   ftcap_hil/report       records, results, plots
    runtime  ftcap_hil/runtime      loops, processes, the daemon's parts
    apps     ftcap_hil/apps, ftcap_hil/__main__.py   composition roots, one per command

Rules: a module imports its own layer or one below; ``bridges`` and ``sim`` do not import each
other; runtime imports no bridge (apps hand the transports in); a bridge folder imports no
other bridge folder; each transport library is imported in its bridge folder only; core
imports numpy/scipy/qpsolvers/proxsuite/daqp and the pure standard library only; sim imports
only what SIM_MAY_IMPORT lists; matplotlib is imported in report only.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

# The order of STYLE.md and the README, lowest first; a comma joins layers of equal rank.
ORDER = "core < ports < bridges, sim < config < report < runtime < apps"
RANK = {
    name.strip(): rank for rank, group in enumerate(ORDER.split("<")) for name in group.split(",")
}
APART = {frozenset({"bridges", "sim"})}  # equal rank, yet neither imports the other
NOT_BELOW = {("runtime", "bridges")}  # below in the order, still not imported: apps wire them
TRANSPORT_HOME = {
    "pymavlink": "bridges/mavlink",
    "serial": "bridges/mavlink",
    "zenoh": "bridges/zenoh_io",
    "can": "bridges/can_io",
    "dronecan": "bridges/can_io",
}
CORE_THIRD_PARTY = {"numpy", "scipy", "qpsolvers", "proxsuite", "daqp"}
IMPURE_STDLIB = {
    "socket", "threading", "time", "subprocess", "select", "selectors", "signal", "asyncio",
    "multiprocessing", "logging", "os", "shutil", "tempfile", "http", "urllib",
}  # fmt: skip
# Everything sim may import (a module or its submodules): pure stdlib parts, numpy, itself,
# and the core's types and plants (never the allocator's machinery).
SIM_MAY_IMPORT = {
    "__future__", "abc", "collections", "dataclasses", "enum", "functools", "itertools",
    "math", "typing", "numpy", "sim",
    "ftcap_hil.core.errors", "ftcap_hil.core.faults", "ftcap_hil.core.messages",
    "ftcap_hil.core.effectiveness", "ftcap_hil.core.models",
}  # fmt: skip
IMPORT_CALLS = {"import_module", "__import__"}


@dataclass(frozen=True)
class Import:
    """One imported name: ``module`` (what ``from`` names, or the module imported) and
    ``full`` (``module.name`` for a ``from`` import, else ``module``); either may be a module."""

    module: str
    full: str
    line: int

    def within(self, allowed: str) -> bool:
        return any(n == allowed or n.startswith(allowed + ".") for n in (self.module, self.full))


def layer_of(path: Path, root: Path) -> str:
    rel = path.relative_to(root).parts
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


def product_files(root: Path) -> list[Path]:
    files = [*(root / "ftcap_hil").rglob("*.py"), *(root / "bridges").rglob("*.py")]
    files += (root / "sim").rglob("*.py")
    return sorted(p for p in files if "data" not in p.relative_to(root).parts)


def package_of(path: Path, root: Path) -> list[str]:
    """The dotted package a module's relative imports start from, as its parts."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    return parts[:-1]  # the file's folder, for a module and a package's __init__ alike


def resolve(name: str, level: int, package: list[str]) -> str:
    """``name`` imported ``level`` dots up from ``package`` (level 0: absolute)."""
    if level == 0:
        return name
    base = package[: len(package) - (level - 1)] if level > 1 else package
    return ".".join([*base, name] if name else base)


def _call_import(node: ast.Call, package: list[str]) -> str | None:
    func = node.func
    called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    if called not in IMPORT_CALLS or not node.args:
        return None
    first = node.args[0]
    if not (isinstance(first, ast.Constant) and isinstance(first.value, str)):
        return None
    name = first.value
    for kw in node.keywords:  # import_module(".x", package="a.b") is a.b.x
        if kw.arg == "package" and isinstance(kw.value, ast.Constant):
            package = str(kw.value.value).split(".")
    dots = len(name) - len(name.lstrip("."))
    return resolve(name.lstrip("."), dots, package)


def imports_of(path: Path, root: Path) -> Iterator[Import]:
    package = package_of(path, root)
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            yield from (Import(a.name, a.name, node.lineno) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            module = resolve(node.module or "", node.level, package)
            yield from (Import(module, f"{module}.{a.name}", node.lineno) for a in node.names)
        elif isinstance(node, ast.Call) and (name := _call_import(node, package)) is not None:
            yield Import(name, name, node.lineno)


def _layer_rule(layer: str, imp: Import, folder: str) -> str | None:
    other = module_layer(imp.full) or module_layer(imp.module)
    if other is None:
        return None
    if other == layer:
        if layer == "bridges" and not imp.within(folder.replace("/", ".")):
            return f"{folder} imports another bridge folder: {imp.full}"
        return None
    if RANK[other] > RANK[layer] or frozenset({layer, other}) in APART:
        return f"{layer} imports {other}: {imp.full}"
    if (layer, other) in NOT_BELOW:
        return f"{layer} imports {other} (apps wire them): {imp.full}"
    return None


def _library_rule(layer: str, imp: Import, folder: str) -> str | None:
    top = imp.module.split(".")[0]
    if top in TRANSPORT_HOME and folder != TRANSPORT_HOME[top]:
        return f"{folder} imports {top} (only {TRANSPORT_HOME[top]} may): {imp.full}"
    if top == "matplotlib" and layer != "report":
        return f"{layer} imports matplotlib (report only): {imp.full}"
    if layer == "sim" and not any(imp.within(a) for a in SIM_MAY_IMPORT):
        return f"sim imports {imp.full}, not in SIM_MAY_IMPORT"
    if layer == "core" and top not in ("ftcap_hil", "bridges", "sim"):
        if top in IMPURE_STDLIB:
            return f"core imports {imp.full} (impure standard library)"
        if top not in CORE_THIRD_PARTY and top not in sys.stdlib_module_names:
            return f"core imports third-party {imp.full}"
    return None


def violations(path: Path, root: Path) -> list[str]:
    """Every broken rule of the module at ``path`` (under ``root``), as ``line: message``."""
    layer = layer_of(path, root)
    folder = "/".join(path.parent.relative_to(root).parts[:2])  # bridges/can_io, ftcap_hil/apps
    out = []
    for imp in imports_of(path, root):
        for rule in (_layer_rule, _library_rule):
            if (found := rule(layer, imp, folder)) is not None:
                out.append(f"{imp.line}: {found}")
    return out
