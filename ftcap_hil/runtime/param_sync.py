"""Live parameters: the :class:`~ftcap_hil.ports.tunables.LiveTunables` a ground station
changed, applied to the daemon in the loop thread.

A bridge's parameter server (the MAVLink ``FTC_*`` table, read through
``bridges.mavlink.allocator_params.AllocatorTunables``) validates and stores a set in its own
thread and bumps its ``generation``; :class:`ParamSync`, run by the daemon before each
cycle, notices the new generation and calls :func:`apply_tunables`, so the core is only ever
touched by the loop.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Protocol

from ftcap_hil.ports.tunables import LiveTunables
from ftcap_hil.runtime.daemon import AllocatorDaemon

log = logging.getLogger(__name__)


class TunableSource(Protocol):
    """What is read of the parameter server: its change counter and its values."""

    @property
    def generation(self) -> int: ...
    def tunables(self) -> LiveTunables: ...


def apply_tunables(daemon: AllocatorDaemon, t: LiveTunables) -> None:
    """Loop thread: bring the daemon in line with ``t``: mode (the core rebuilt, the
    command kept), watchdog timeouts (s), allocator weights and dead threshold, dither
    amplitude and probe interval."""
    if t.mode is not daemon.config.core.mode:
        daemon.set_mode(t.mode)
        log.info("mode -> %s", t.mode.value)
    daemon.config = dataclasses.replace(
        daemon.config,
        setpoint_timeout_s=t.setpoint_timeout_s,
        telemetry_timeout_s=t.telemetry_timeout_s,
        esc_timeout_s=t.esc_timeout_s,
    )
    core = daemon.core
    core.retune(
        allocator=dataclasses.replace(
            core.config.allocator,
            slack_weight=t.slack_weight,
            effort_weight=t.effort_weight,
            dead_threshold=t.dead_threshold,
        ),
        excitation=dataclasses.replace(
            core.config.excitation,
            dither_amplitude=t.dither_amplitude,
            probe_interval=t.probe_interval,
        ),
    )
    daemon.config = dataclasses.replace(daemon.config, core=core.config)


class ParamSync:
    """A ``before_cycle`` hook: applies the tunables when their generation moved."""

    def __init__(self, daemon: AllocatorDaemon, params: TunableSource) -> None:
        self._daemon = daemon
        self._params = params
        self._seen = -1
        self.applied = 0  # how many generations were applied

    def __call__(self) -> None:
        generation = self._params.generation
        if generation != self._seen:
            self._seen = generation
            apply_tunables(self._daemon, self._params.tunables())
            self.applied += 1
