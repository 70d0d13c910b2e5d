"""Every test carries the marker of its tier, given by its folder, so that ``pytest -m unit``
(or ``contract``, ``closed_loop``, ``e2e``, ``vcan``, ``docker``) runs one tier; markers a
module sets itself (``e2e`` on a docker test that starts containers) are kept."""

from __future__ import annotations

from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
TIERS = ("unit", "contract", "closed_loop", "e2e", "vcan", "docker")


def tier_of(path: Path) -> str | None:
    """The tier of a test file: the first folder under tests/, if it is one of TIERS."""
    try:
        folder = path.resolve().relative_to(TESTS).parts[0]
    except ValueError:
        return None
    return folder if folder in TIERS else None


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        tier = tier_of(item.path)
        if tier is not None:
            item.add_marker(tier)
