"""The allocator's MAVLink parameter table (``FTC_*``), the FTC_MODE codes, and the table
read as the daemon's :class:`~ftcap_hil.ports.tunables.LiveTunables`."""

from __future__ import annotations

import math
from collections.abc import Mapping

from bridges.mavlink.params import ParamServer, ParamSpec, ParamType
from ftcap_hil.core.cycle import CoreConfig
from ftcap_hil.core.status import Mode
from ftcap_hil.ports.tunables import LiveTunables

# Modes a running daemon may switch to, by FTC_MODE value (oracle needs the truth: never).
MODE_CODES = {0: Mode.NONE, 1: Mode.CAP, 2: Mode.FTCAP, 3: Mode.FTCAP_LITERAL}
CODE_OF_MODE = {mode: code for code, mode in MODE_CODES.items()}
_MODES = "0 none, 1 cap, 2 ftcap, 3 ftcap-literal"


def _timeout(name: str, value_s: float, description: str) -> ParamSpec:
    """A watchdog timeout in seconds, settable while running within [0.01, 60]."""
    return ParamSpec(name, value_s, min=0.01, max=60.0, description=description)


def _restart_only(
    name: str, value: float, low: float, high: float, what: str, kind: ParamType = ParamType.FLOAT
) -> ParamSpec:
    """A parameter that is refused while the daemon runs (it needs a restart)."""
    return ParamSpec(name, value, kind, low, high, settable_while_running=False, description=what)


def allocator_param_specs(
    core: CoreConfig,
    setpoint_timeout_s: float,
    telemetry_timeout_s: float,
    esc_timeout_s: float,
    rate_hz: float,
    u_max_n: float,
) -> list[ParamSpec]:
    """The tunables exposed over MAVLink. Refused while running, and why:
    FTC_WINDOW sizes the estimator's buffers (changing it would discard the window),
    FTC_RATE_HZ fixes the deadlines and the per-cycle rate limits, FTC_UMAX is the
    hardware's amplitude limit from the vessel file: restart with a new config instead."""
    c, INT = core, ParamType.INT
    mode = ParamSpec("FTC_MODE", CODE_OF_MODE[c.mode], INT, 0, 3, description=_MODES)
    return [
        mode,
        _timeout("FTC_SP_TMO", setpoint_timeout_s, "setpoint timeout (s) -> zero thrust"),
        _timeout("FTC_TLM_TMO", telemetry_timeout_s, "telemetry timeout (s) -> estimation frozen"),
        _timeout("FTC_ESC_TMO", esc_timeout_s, "ESC silence (s) -> thruster failed"),
        ParamSpec("FTC_SLACK_W", c.allocator.slack_weight, min=1e-3, max=1e12),
        ParamSpec("FTC_EFFORT_W", c.allocator.effort_weight, min=1e-9, max=1e6),
        ParamSpec("FTC_DEAD_THR", c.allocator.dead_threshold, min=0.0, max=0.99),
        ParamSpec("FTC_DITHER", c.excitation.dither_amplitude, min=0.0, max=0.5),
        ParamSpec("FTC_PROBE_INT", c.excitation.probe_interval, INT, 0, 1e6),
        _restart_only(
            "FTC_WINDOW", c.estimator.window, 2, 10000, "estimator window (restart)", INT
        ),
        _restart_only("FTC_RATE_HZ", rate_hz, 0.1, 2000.0, "loop rate (restart)"),
        _restart_only("FTC_UMAX", u_max_n, 0.0, math.inf, "thruster limit (vessel file)"),
    ]


def tunables_of(values: Mapping[str, float]) -> LiveTunables:
    """The live-settable part of the table ``values`` (by FTC_* name); KeyError for an
    FTC_MODE code no mode has."""
    return LiveTunables(
        mode=MODE_CODES[int(values["FTC_MODE"])],
        setpoint_timeout_s=values["FTC_SP_TMO"],
        telemetry_timeout_s=values["FTC_TLM_TMO"],
        esc_timeout_s=values["FTC_ESC_TMO"],
        slack_weight=values["FTC_SLACK_W"],
        effort_weight=values["FTC_EFFORT_W"],
        dead_threshold=values["FTC_DEAD_THR"],
        dither_amplitude=values["FTC_DITHER"],
        probe_interval=int(values["FTC_PROBE_INT"]),
    )


class AllocatorTunables:
    """A parameter server holding the FTC_* table, read as :class:`LiveTunables`.

    ``generation`` moves on every accepted change (the server's own); ``set_running``
    tells the server whether the restart-only parameters are refused now.
    """

    def __init__(self, server: ParamServer) -> None:
        self._server = server

    @property
    def generation(self) -> int:
        return self._server.generation

    def tunables(self) -> LiveTunables:
        """The table's values now (:func:`tunables_of`)."""
        return tunables_of(self._server.values())

    def set_running(self, running: bool) -> None:
        """While running, the restart-only parameters (FTC_WINDOW, ...) are refused."""
        self._server.set_running(running)
