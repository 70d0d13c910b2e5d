"""The test tree is its tiers: each folder under tests/ is a tier (its tests carry its marker,
tests/conftest.py) or tests/support (helpers, no tests)."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

from tests.conftest import TIERS, tier_of

TESTS = Path(__file__).resolve().parents[1]


def test_every_folder_is_a_tier_or_support() -> None:
    folders = {p.name for p in TESTS.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert folders == {*TIERS, "support"}
    assert sorted(p.name for p in TESTS.glob("test_*.py")) == []


def test_support_holds_no_tests() -> None:
    for path in (TESTS / "support").rglob("*.py"):
        assert not path.name.startswith("test_"), path
        tree = ast.parse(path.read_text())
        tests = [n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)]
        assert not [t for t in tests if t.startswith("test_")], path


def test_the_tier_markers_are_registered() -> None:
    config = tomllib.loads((TESTS.parent / "pyproject.toml").read_text())
    markers = {m.split(":")[0] for m in config["tool"]["pytest"]["ini_options"]["markers"]}
    assert markers >= {*TIERS, "slow"}


def test_a_file_is_in_the_tier_of_its_first_folder() -> None:
    assert tier_of(TESTS / "unit" / "test_x.py") == "unit"
    assert tier_of(TESTS / "closed_loop" / "test_x.py") == "closed_loop"
    assert tier_of(TESTS / "support" / "vessels.py") is None
    assert tier_of(TESTS.parent / "bench" / "cycle.py") is None


def test_this_test_carries_the_unit_marker(request: pytest.FixtureRequest) -> None:
    assert request.node.get_closest_marker("unit") is not None
    assert request.node.get_closest_marker("e2e") is None
