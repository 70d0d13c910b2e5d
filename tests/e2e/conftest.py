"""Fixtures of the end-to-end tests: ``hil``, a rig (tests/e2e/rig.py) with the CAN hub
running; the test starts the allocator and the sim it needs. Every child is killed by PID at
teardown, and the child logs are printed when the test failed."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.e2e.rig import Rig


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    outcome: Any = yield
    rep = outcome.get_result()
    setattr(item, f"rep_{rep.when}", rep)


@pytest.fixture
def hil(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[Rig]:
    """A rig with the CAN hub running; the test starts the allocator and the sim it needs."""
    rig = Rig(tmp_path)
    try:
        rig.start_hub()
        yield rig
    finally:
        failed = any(
            getattr(getattr(request.node, f"rep_{w}", None), "failed", False)
            for w in ("setup", "call")
        )
        try:
            rig.teardown()
        finally:
            if failed:
                print(rig.logs())
