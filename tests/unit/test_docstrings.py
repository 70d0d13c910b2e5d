"""Every public name of the core, the ports and the bridges has a docstring (STYLE.md, docs).

Each module under ``ftcap_hil/core``, ``ftcap_hil/ports`` and ``bridges`` is read with
``ast`` (nothing is imported). Public means no leading underscore. Checked: module-level
functions and classes, and the methods of every class (a private base's public methods are
inherited by public links, so they count too), nested classes included. Exempt: dunder
methods (``__init__`` and the like: the class docstring says what the constructor takes),
properties (``@property``, ``@functools.cached_property`` and their setters/deleters: a
one-line attribute whose name and type say what it is) and ``@typing.overload`` stubs.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FOLDERS = ("ftcap_hil/core", "ftcap_hil/ports", "bridges")
_EXEMPT_DECORATORS = {"property", "cached_property", "setter", "deleter", "overload"}

Definition = ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef


def modules() -> list[Path]:
    return sorted(p for folder in FOLDERS for p in (ROOT / folder).rglob("*.py"))


def _decorator_names(node: Definition) -> set[str]:
    names = set()
    for dec in node.decorator_list:
        target = dec.func if isinstance(dec, ast.Call) else dec
        if isinstance(target, ast.Attribute):
            names.add(target.attr)
        elif isinstance(target, ast.Name):
            names.add(target.id)
    return names


def _exempt(node: Definition, in_class: bool) -> bool:
    if node.name.startswith("_"):
        return True
    is_function = not isinstance(node, ast.ClassDef)
    return is_function and in_class and bool(_decorator_names(node) & _EXEMPT_DECORATORS)


def public_definitions(body: list[ast.stmt], prefix: str = "") -> Iterator[tuple[str, Definition]]:
    """(qualified name, node) of every definition in ``body`` that needs a docstring."""
    for node in body:
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            continue
        if isinstance(node, ast.ClassDef):
            # A private class is not checked itself, but its public methods are.
            if not node.name.startswith("_"):
                yield f"{prefix}{node.name}", node
            yield from public_definitions(node.body, f"{prefix}{node.name}.")
        elif not _exempt(node, in_class=bool(prefix)):
            yield f"{prefix}{node.name}", node


def undocumented(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    rel = path.relative_to(ROOT)
    return [
        f"{rel}:{node.lineno} {name}"
        for name, node in public_definitions(tree.body)
        if ast.get_docstring(node) is None
    ]


def test_every_public_function_class_and_method_has_a_docstring() -> None:
    missing = [entry for path in modules() for entry in undocumented(path)]
    assert not missing, f"{len(missing)} public definitions without a docstring:\n" + "\n".join(
        missing
    )


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("def f(): pass\n", ["f"]),
        ("def _f(): pass\n", []),
        ('class C:\n    """Doc."""\n    def m(self): pass\n', ["C.m"]),
        ('class C:\n    """Doc."""\n    @property\n    def p(self): return 1\n', []),
        ('class C:\n    """Doc."""\n    def __init__(self): pass\n', []),
        ("class _P:\n    def shutdown(self): pass\n", ["_P.shutdown"]),
        ('def f():\n    """Doc."""\n', []),
    ],
)
def test_the_checker_sees_what_it_should(source: str, expected: list[str]) -> None:
    """The rule itself can fail: an undocumented function or method is reported."""
    tree = ast.parse(source)
    found = [n for n, node in public_definitions(tree.body) if ast.get_docstring(node) is None]
    assert found == expected
