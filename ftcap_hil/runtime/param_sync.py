"""Live parameters: the ``FTC_*`` table (bridges/mavlink/allocator_params.py) applied to the
daemon, in the loop thread, whenever a ground station changed one.

The bridge's parameter server validates and stores a set in its own thread and bumps its
``generation``; :class:`ParamSync`, run by the daemon before each cycle, notices the new
generation and calls :func:`apply_params`, so the core is only ever touched by the loop.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Protocol

from bridges.mavlink.allocator_params import MODE_CODES
from ftcap_hil.runtime.daemon import AllocatorDaemon

log = logging.getLogger(__name__)


class ParamTable(Protocol):
    """What is read of the parameter server (``bridges.mavlink.params.ParamServer``)."""

    @property
    def generation(self) -> int: ...
    def values(self) -> dict[str, float]: ...


def apply_params(daemon: AllocatorDaemon, values: dict[str, float]) -> None:
    """Loop thread: bring the daemon in line with the parameter table ``values`` (by FTC_*
    name): mode (the core rebuilt, the command kept), watchdog timeouts (s), allocator
    weights and dead threshold, dither amplitude and probe interval."""
    mode = MODE_CODES[int(values["FTC_MODE"])]
    if mode is not daemon.config.core.mode:
        daemon.set_mode(mode)
        log.info("mode -> %s", mode.value)
    daemon.config = dataclasses.replace(
        daemon.config,
        setpoint_timeout_s=values["FTC_SP_TMO"],
        telemetry_timeout_s=values["FTC_TLM_TMO"],
        esc_timeout_s=values["FTC_ESC_TMO"],
    )
    core = daemon.core
    core.retune(
        allocator=dataclasses.replace(
            core.config.allocator,
            slack_weight=values["FTC_SLACK_W"],
            effort_weight=values["FTC_EFFORT_W"],
            dead_threshold=values["FTC_DEAD_THR"],
        ),
        excitation=dataclasses.replace(
            core.config.excitation,
            dither_amplitude=values["FTC_DITHER"],
            probe_interval=int(values["FTC_PROBE_INT"]),
        ),
    )
    daemon.config = dataclasses.replace(daemon.config, core=core.config)


class ParamSync:
    """A ``before_cycle`` hook: applies the table when its generation moved."""

    def __init__(self, daemon: AllocatorDaemon, params: ParamTable) -> None:
        self._daemon = daemon
        self._params = params
        self._seen = -1
        self.applied = 0  # how many generations were applied

    def __call__(self) -> None:
        generation = self._params.generation
        if generation != self._seen:
            self._seen = generation
            apply_params(self._daemon, self._params.values())
            self.applied += 1
