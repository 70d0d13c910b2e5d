"""The ESC watchdog: which thrusters the allocator treats as failed because their ESC is silent.

Each ESC's status age (seconds since its last ``esc.Status``, +inf if never heard) against
``timeout_s``:

* heard within ``timeout_s``: working;
* heard once, silent since for longer: **failed** (warning "ESC n silent: thruster failed");
* never heard: held at zero like a failed one, but announced as **waiting** (info "ESC n not
  heard yet") because at start-up the vessel may simply not be powered yet. It becomes a
  failure only once another ESC has been reporting for ``timeout_s`` (the *others-up* rule:
  the bus and the vessel are alive, this ESC is not).

Announcements go through a :class:`~ftcap_hil.runtime.transitions.TransitionLog`, so each is
made once when it starts and once when it ends.
"""

from __future__ import annotations

import numpy as np

from ftcap_hil.core.messages import BoolArray, FloatArray
from ftcap_hil.core.status import Severity
from ftcap_hil.runtime.transitions import TransitionLog


class EscWatchdog:
    """Failed/waiting policy over ESC status ages (module docstring)."""

    def __init__(self, transitions: TransitionLog) -> None:
        self._transitions = transitions
        self._bus_alive_ns: int | None = None  # when the first ESC was heard

    def failed(self, now_ns: int, ages_s: FloatArray, timeout_s: float) -> BoolArray:
        """(m,) True for every thruster to allocate as failed at ``now_ns``: silent for over
        ``timeout_s`` or never heard (announced as waiting or failed, module docstring)."""
        failed = ages_s > timeout_s  # never heard: age +inf, held at zero as well
        heard = np.isfinite(ages_s)
        if self._bus_alive_ns is None and heard.any():
            self._bus_alive_ns = now_ns
        others_up = self._bus_alive_ns is not None and now_ns - self._bus_alive_ns > timeout_s * 1e9
        for i in range(failed.size):
            n = i + 1
            self._transitions.update(
                f"esc-wait{n}",
                not heard[i],
                f"ESC {n} not heard yet: thruster held at 0",
                f"ESC {n} reporting",
                severity=Severity.INFO,
            )
            self._transitions.update(
                f"esc{n}",
                bool(failed[i]) and bool(heard[i] or others_up),
                f"ESC {n} silent: thruster failed",
                f"ESC {n} reporting again",
            )
        return failed
