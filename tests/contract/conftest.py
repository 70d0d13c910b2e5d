"""Fixtures of the contract tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.support.mavlink_peers import mavlink_threads, wait_until


@pytest.fixture
def no_leaked_threads() -> Iterator[None]:
    """Fails the test if a MAVLink link's dispatch thread outlives it."""
    yield
    wait_until(lambda: not mavlink_threads(), 3.0)
    assert not mavlink_threads(), f"leaked: {mavlink_threads()}"
