"""Run the allocator daemon: setpoints and telemetry in (MAVLink, Zenoh), thrusters out (CAN).

Configuration: ``--config FILE`` (default: the shipped ftcap_hil/data/hil/allocator.toml) and
``--set SECTION.KEY=VALUE`` overrides. SIGINT/SIGTERM: a zero command, then exit 0.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import logging
import sys
import time
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from ftcap_hil.config.daemon import LoadedConfig, load_daemon_config
from ftcap_hil.core.cycle import Mode
from ftcap_hil.core.geometry import ConfigError
from ftcap_hil.core.messages import AllocatorStatus, FloatArray, ThrusterCommand
from ftcap_hil.runtime.daemon import AllocatorDaemon, Ports

log = logging.getLogger("ftcap_hil.core.allocator")

# Modes a running daemon may switch to, by FTC_MODE value (oracle needs the truth: never).
MODE_CODES = {0: Mode.NONE, 1: Mode.CAP, 2: Mode.FTCAP, 3: Mode.FTCAP_LITERAL}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", type=Path, help="daemon TOML (default: shipped allocator.toml)")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override a config value (repeatable)",
    )
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument(
        "--command-log", type=Path, help="CSV of every command sent (monotonic ns, u_1..u_m in N)"
    )


class CommandLog:
    """The allocator's own record of every command it issued, for capture cross-checks.

    A command the bus refused is still a row (the exit log line counts the refusals), so the
    stamps show the loop's rhythm even while the interface is down. The CAN adapter's own
    final zero on close comes after the daemon's logged zero and is not a row."""

    def __init__(self, path: Path, m: int) -> None:
        self._fh: TextIO = open(path, "w", newline="")  # noqa: SIM115 - closed in close()
        self._w = csv.writer(self._fh)
        self._w.writerow(["stamp_ns", *[f"u_{i}" for i in range(1, m + 1)]])

    def write(self, stamp_ns: int, u: FloatArray) -> None:
        self._w.writerow([stamp_ns, *[f"{v:.9g}" for v in u]])

    def close(self) -> None:
        self._fh.close()


class LoggedSink:
    """Wraps the CAN sink: every command (zeros included) also goes to the command log."""

    def __init__(self, inner: Any, log_: CommandLog | None) -> None:
        self._inner, self._log = inner, log_

    def send(self, u: FloatArray) -> bool:
        ok = bool(self._inner.send(u))
        if self._log is not None:
            self._log.write(time.monotonic_ns(), u)
        return ok

    def send_zero(self) -> bool:
        return self.send(np.zeros(self._inner.force_map.m))

    def tick(self, now_ns: int | None = None) -> Any:
        return self._inner.tick(now_ns)


class MavlinkStatus:
    """Daemon status -> ACTUATOR_OUTPUT_STATUS + FTCAP_STATUS; announcements -> STATUSTEXT."""

    def __init__(self, link: Any, mav: Any) -> None:
        self._link, self._mav = link, mav

    def publish(self, st: AllocatorStatus) -> None:
        mav = self._mav
        # The first publish comes from the first cycle: it ends the link's BOOT state.
        state = mav.SystemStatus.STANDBY if st.setpoint_stale else mav.SystemStatus.ACTIVE
        self._link.set_system_status(state)
        flags = mav.StatusFlag.NONE
        for on, flag in (
            (st.degraded, "DEGRADED"),
            (st.setpoint_stale, "SETPOINT_STALE"),
            (st.telemetry_stale, "TELEMETRY_STALE"),
            (any(st.faulty), "FAULT_DETECTED"),
            (any(st.saturated), "SATURATED"),
            (max(map(abs, st.unallocated), default=0.0) > 1e-6, "UNALLOCATED"),
        ):
            if on:
                flags |= mav.StatusFlag[flag]
        self._link.send_thruster_commands(ThrusterCommand.checked(st.u))
        if st.esc_age_s:
            self._link.send_esc_status(st.esc_rpm, st.esc_current_a, st.esc_age_s, st.esc_failed)
        self._link.send_status(
            mav.AllocatorStatus(
                np.asarray(st.tau_demand),
                np.asarray(st.unallocated),
                np.asarray(st.delta_hat),
                np.asarray(st.f_hat),
                flags,
            )
        )

    def announce(self, text: str, severity: str) -> None:
        sev = self._mav.Severity.WARNING if severity == "warning" else self._mav.Severity.INFO
        self._link.send_statustext(text, sev)


class ZenohStatus:
    def __init__(self, link: Any, zc: Any) -> None:
        self._link, self._zc = link, zc

    def publish(self, st: AllocatorStatus) -> None:
        self._link.publish_thruster_command(ThrusterCommand.checked(st.u))
        self._link.publish_status(
            self._zc.AllocatorStatus(
                mode=st.mode,
                cycle=st.cycle,
                overruns=st.overruns,
                degraded=st.degraded,
                delta_hat=np.asarray(st.delta_hat),
                f_hat=np.asarray(st.f_hat),
                bf_hat=np.asarray(st.bf_hat),
                u=np.asarray(st.u),
                tau_unallocated=np.asarray(st.unallocated),
                saturated=tuple(st.saturated),
                port_age_s={
                    "setpoint": st.setpoint_age_s,
                    "telemetry": st.telemetry_age_s,
                    **{f"esc{i + 1}": a for i, a in enumerate(st.esc_age_s)},
                },
                stale={"setpoint": st.setpoint_stale, "telemetry": st.telemetry_stale},
            )
        )

    def announce(self, text: str, severity: str) -> None:
        log.debug("zenoh carries no text channel: %s", text)


def param_specs(cfg: LoadedConfig) -> list[Any]:
    """The tunables exposed over MAVLink. Refused while running, and why:
    FTC_WINDOW sizes the estimator's buffers (changing it would discard the window),
    FTC_RATE_HZ fixes the deadlines and the per-cycle rate limits, FTC_UMAX is the
    hardware's amplitude limit from the vessel file: restart with a new config instead."""
    from bridges.mavlink.params import ParamSpec, ParamType

    d, c = cfg.daemon, cfg.daemon.core
    mode_code = {v: k for k, v in MODE_CODES.items()}[c.mode]
    inf = float("inf")
    return [
        ParamSpec(
            "FTC_MODE",
            mode_code,
            ParamType.INT,
            0,
            3,
            description="0 none, 1 cap, 2 ftcap, 3 ftcap-literal",
        ),
        ParamSpec(
            "FTC_SP_TMO",
            d.setpoint_timeout_s,
            min=0.01,
            max=60.0,
            description="setpoint timeout (s) -> zero thrust",
        ),
        ParamSpec(
            "FTC_TLM_TMO",
            d.telemetry_timeout_s,
            min=0.01,
            max=60.0,
            description="telemetry timeout (s) -> estimation frozen",
        ),
        ParamSpec(
            "FTC_ESC_TMO",
            d.esc_timeout_s,
            min=0.01,
            max=60.0,
            description="ESC silence (s) -> thruster failed",
        ),
        ParamSpec("FTC_SLACK_W", c.allocator.slack_weight, min=1e-3, max=1e12),
        ParamSpec("FTC_EFFORT_W", c.allocator.effort_weight, min=1e-9, max=1e6),
        ParamSpec("FTC_DEAD_THR", c.allocator.dead_threshold, min=0.0, max=0.99),
        ParamSpec("FTC_DITHER", c.excitation.dither_amplitude, min=0.0, max=0.5),
        ParamSpec("FTC_PROBE_INT", c.excitation.probe_interval, ParamType.INT, 0, 1e6),
        ParamSpec(
            "FTC_WINDOW",
            c.estimator.window,
            ParamType.INT,
            2,
            10000,
            settable_while_running=False,
            description="estimator window (restart)",
        ),
        ParamSpec(
            "FTC_RATE_HZ",
            d.rate_hz,
            min=0.1,
            max=2000.0,
            settable_while_running=False,
            description="loop rate (restart)",
        ),
        ParamSpec(
            "FTC_UMAX",
            float(np.max(d.thrusters.u_max)),
            min=0.0,
            max=inf,
            settable_while_running=False,
            description="thruster limit (vessel file)",
        ),
    ]


def apply_params(daemon: AllocatorDaemon, values: dict[str, float]) -> None:
    """Loop thread: bring the daemon in line with the parameter table."""
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


def _section(cfg: LoadedConfig, name: str) -> dict[str, Any]:
    table = cfg.raw.get(name, {})
    if not isinstance(table, dict):
        raise ConfigError(f"{cfg.source}.{name}: expected a table")
    return dict(table)


def open_can(cfg: LoadedConfig, stack: contextlib.ExitStack) -> tuple[Any, Any]:
    from bridges.can_io.adapters import CanEscStatusSource, CanThrusterSink
    from bridges.can_io.bus import open_can_bus
    from bridges.can_io.force_map import ForceRawMap

    c = _section(cfg, "can")
    ths = cfg.daemon.thrusters
    bus = stack.enter_context(
        open_can_bus(str(c.get("interface", "canhub")), str(c.get("channel", "127.0.0.1:29536")))
    )
    fmap = ForceRawMap.from_limits(ths.u_min, ths.u_max, float(c.get("deadband_n", 0.0)))
    sink = stack.enter_context(
        CanThrusterSink(bus, fmap, node_id=int(c.get("node_id", 10)), zero_on_shutdown=True)
    )
    esc_ids = c.get("esc_node_ids")
    esc = None
    if c.get("esc_monitor", True):
        esc = stack.enter_context(CanEscStatusSource(bus, ths.m, esc_node_ids=esc_ids))
    return sink, esc


def build_ports(
    cfg: LoadedConfig,
    stack: contextlib.ExitStack,
    cmd_log: CommandLog | None,
) -> tuple[Ports, Any]:
    sink, esc = open_can(cfg, stack)
    ports = Ports(
        setpoints=[],
        telemetry=[],
        thrusters=LoggedSink(sink, cmd_log),
        esc_ages=esc.ages_s if esc is not None else None,
    )
    params = None
    mav_cfg = _section(cfg, "mavlink")
    if mav_cfg.pop("enabled", True):
        from bridges.mavlink import allocator as mav
        from bridges.mavlink.config import MavlinkEndpoint, default_allocator_endpoint

        max_wrench = tuple(mav_cfg.pop("max_wrench", (0.3, 0.3, 0.06)))
        limit = mav_cfg.pop("wrench_limit", None)
        endpoint = MavlinkEndpoint.from_mapping("mavlink", mav_cfg, default_allocator_endpoint())
        link = stack.enter_context(
            mav.MavlinkAllocatorLink(
                mav.AllocatorLinkConfig(
                    cfg.daemon.thrusters.m, max_wrench, None if limit is None else tuple(limit)
                ),
                endpoint,
                param_specs(cfg),
            )
        )
        ports.setpoints += [link.setpoint, link.manual]
        ports.telemetry.append(link.odometry)
        ports.status.append(MavlinkStatus(link, mav))
        params = link.params
    z_cfg = _section(cfg, "zenoh")
    if z_cfg.pop("enabled", True):
        from bridges.zenoh_io import codec as zenoh_codec
        from bridges.zenoh_io import config as zenoh_config
        from bridges.zenoh_io import link as zenoh_link

        conf_name = str(z_cfg.get("config", "allocator.json5"))
        path = Path(conf_name)
        if not path.exists():
            path = zenoh_config.shipped_config_path(conf_name.removesuffix(".json5"))
        conf = zenoh_link.load_config(path, list(z_cfg.get("overrides", [])))
        zl = stack.enter_context(
            zenoh_link.ZenohAllocatorLink(str(z_cfg.get("vessel", "ftcap1")), conf)
        )
        ports.setpoints.append(zl.setpoints)
        ports.telemetry.append(zl.odometry)
        ports.status.append(ZenohStatus(zl, zenoh_codec))
    return ports, params


def run(args: argparse.Namespace) -> int:
    try:
        cfg = load_daemon_config(args.config, args.set)
    except (ConfigError, ValueError) as e:
        print(f"ftcap-hil allocator: {e}", file=sys.stderr)
        return 2
    with contextlib.ExitStack() as stack:
        cmd_log = None
        if args.command_log:
            cmd_log = CommandLog(args.command_log, cfg.daemon.thrusters.m)
            stack.callback(cmd_log.close)
        try:
            ports, params = build_ports(cfg, stack, cmd_log)
        except (ConfigError, ValueError, RuntimeError, OSError) as e:
            print(f"ftcap-hil allocator: start-up failed: {e}", file=sys.stderr)
            return 2
        daemon = AllocatorDaemon(cfg.daemon, ports)
        if params is not None:
            seen = [-1]

            def sync_params() -> None:
                if params.generation != seen[0]:
                    seen[0] = params.generation
                    apply_params(daemon, params.values())

            daemon.before_cycle.append(sync_params)
            params.set_running(True)
        if args.duration:
            stop_at = time.monotonic() + args.duration
            daemon.before_cycle.append(
                lambda: daemon.request_exit() if time.monotonic() > stop_at else None
            )
        log.info(
            "allocator: %s, %.1f Hz, %d thrusters, mode %s, %d setpoint / %d telemetry ports",
            cfg.source,
            cfg.daemon.rate_hz,
            cfg.daemon.thrusters.m,
            cfg.daemon.core.mode.value,
            len(ports.setpoints),
            len(ports.telemetry),
        )
        code = daemon.run()
        if daemon.cycle_ns:
            c = np.array(daemon.cycle_ns) * 1e-3
            log.info(
                "cycle time: median %.0f us, p99 %.0f us, p99.9 %.0f us, max %.0f us",
                np.median(c),
                np.percentile(c, 99),
                np.percentile(c, 99.9),
                c.max(),
            )
        if daemon.reaction_ns:
            r = np.array(daemon.reaction_ns) * 1e-3
            log.info(
                "setpoint received -> command sent: median %.0f us, p99 %.0f us (n=%d)",
                np.median(r),
                np.percentile(r, 99),
                r.size,
            )
        malformed = sum(b.malformed for b in ports.setpoints) + sum(
            b.malformed for b in ports.telemetry
        )
        log.info(
            "allocator: stopped after %d cycles, %d overruns, %d commands refused by the bus, "
            "%d malformed inputs dropped",
            daemon.cycles,
            daemon.overruns,
            daemon.not_sent,
            malformed,
        )
        return code
