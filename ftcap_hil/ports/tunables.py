"""What a ground station may change while the allocator runs, in the project's terms.

A bridge's parameter table (``bridges.mavlink.allocator_params``: the ``FTC_*`` table)
reads its values as one :class:`LiveTunables`; the daemon applies it in its loop
(:mod:`ftcap_hil.runtime.param_sync`).
"""

from __future__ import annotations

from dataclasses import dataclass

from ftcap_hil.core.status import Mode


@dataclass(frozen=True)
class LiveTunables:
    """The allocator's mode; its watchdog timeouts (s): setpoint (-> zero thrust), telemetry
    (-> estimation frozen), ESC silence (-> thruster failed); the allocator's slack and effort
    weights and dead threshold; the dither amplitude and the probe interval (cycles)."""

    mode: Mode
    setpoint_timeout_s: float
    telemetry_timeout_s: float
    esc_timeout_s: float
    slack_weight: float
    effort_weight: float
    dead_threshold: float
    dither_amplitude: float
    probe_interval: int
