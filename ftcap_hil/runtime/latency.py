"""The allocator's timing record: how long each cycle took and how fast a setpoint acts.

``cycle`` is the duration of one cycle's work (collect -> estimate -> allocate -> send ->
status); ``reaction`` the time from a setpoint's arrival in its mailbox (its stamp) to its
command being handed to the thruster sink, once per new setpoint. Both in ns on
CLOCK_MONOTONIC, kept for the last ``max_samples`` and summarised on exit.
"""

from __future__ import annotations

from collections import deque

import numpy as np


class LatencyStats:
    """Bounded records of cycle durations and setpoint reactions (module docstring)."""

    def __init__(self, max_samples: int = 200_000) -> None:
        self.cycle_ns: deque[int] = deque(maxlen=max_samples)
        self.reaction_ns: deque[int] = deque(maxlen=max_samples)

    def cycle(self, duration_ns: int) -> None:
        self.cycle_ns.append(duration_ns)

    def reaction(self, latency_ns: int) -> None:
        self.reaction_ns.append(latency_ns)

    def summary_lines(self) -> list[str]:
        """Percentiles in us for the exit log; nothing for a record still empty."""
        lines = []
        if self.cycle_ns:
            c = np.array(self.cycle_ns) * 1e-3
            lines.append(
                f"cycle time: median {np.median(c):.0f} us, p99 {np.percentile(c, 99):.0f} us, "
                f"p99.9 {np.percentile(c, 99.9):.0f} us, max {c.max():.0f} us"
            )
        if self.reaction_ns:
            r = np.array(self.reaction_ns) * 1e-3
            lines.append(
                f"setpoint received -> command sent: median {np.median(r):.0f} us, "
                f"p99 {np.percentile(r, 99):.0f} us (n={r.size})"
            )
        return lines
