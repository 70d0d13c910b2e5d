"""Waiting on a condition while something must keep turning (a DroneCAN node's spin, a
python-can bus's poll): the one poll-until of the contract tests that drive a client."""

from __future__ import annotations

import time
from collections.abc import Callable


def spin_until(cond: Callable[[], bool], timeout_s: float, spin: Callable[[], None]) -> bool:
    """Call ``spin`` until ``cond()`` holds or ``timeout_s`` has passed; the last answer."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        spin()
        if cond():
            return True
    return cond()
