"""Run the allocator daemon: setpoints and telemetry in (MAVLink, Zenoh), thrusters out (CAN).

Configuration: ``--config FILE`` (default: the shipped ftcap_hil/data/hil/allocator.toml) and
``--set SECTION.KEY=VALUE`` overrides. SIGINT/SIGTERM: a zero command, then exit 0.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.config.daemon import LoadedConfig, load_daemon_config
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.runtime.command_log import CommandLog, LoggedSink
from ftcap_hil.runtime.daemon import AllocatorDaemon, Ports

log = logging.getLogger(__name__)


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


def apply_params(daemon: AllocatorDaemon, values: dict[str, float]) -> None:
    """Loop thread: bring the daemon in line with the parameter table."""
    from bridges.mavlink.allocator_params import MODE_CODES

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


def open_can(cfg: LoadedConfig, stack: contextlib.ExitStack) -> tuple[Any, Any]:
    from bridges.can_io.adapters import CanEscStatusSource, CanThrusterSink
    from bridges.can_io.bus import open_can_bus
    from bridges.can_io.force_map import ForceRawMap

    c = cfg.ports.can
    ths = cfg.daemon.thrusters
    bus = stack.enter_context(open_can_bus(c.interface, c.channel))
    fmap = ForceRawMap.from_limits(ths.u_min, ths.u_max, c.deadband_n)
    sink = stack.enter_context(CanThrusterSink(bus, fmap, node_id=c.node_id, zero_on_shutdown=True))
    esc = None
    if c.esc_monitor:
        esc = stack.enter_context(CanEscStatusSource(bus, ths.m, esc_node_ids=c.esc_node_ids))
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
        thrusters=LoggedSink(sink, cfg.daemon.thrusters.m, cmd_log),
        esc_ages=esc.ages_s if esc is not None else None,
    )
    params = None
    if (mav_cfg := cfg.ports.mavlink) is not None:
        from bridges.mavlink import allocator as mav
        from bridges.mavlink.allocator_params import allocator_param_specs
        from bridges.mavlink.status import MavlinkStatusSink

        d = cfg.daemon
        link = stack.enter_context(
            mav.MavlinkAllocatorLink(
                mav.AllocatorLinkConfig(
                    cfg.daemon.thrusters.m, mav_cfg.max_wrench, mav_cfg.wrench_limit
                ),
                mav_cfg.endpoint,
                allocator_param_specs(
                    d.core,
                    d.setpoint_timeout_s,
                    d.telemetry_timeout_s,
                    d.esc_timeout_s,
                    d.rate_hz,
                    float(np.max(d.thrusters.u_max)),
                ),
            )
        )
        ports.setpoints += [link.setpoint, link.manual]
        ports.telemetry.append(link.odometry)
        ports.status.append(MavlinkStatusSink(link))
        params = link.params
    if (z_cfg := cfg.ports.zenoh) is not None:
        from bridges.zenoh_io import link as zenoh_link
        from bridges.zenoh_io.status import ZenohStatusSink

        conf = zenoh_link.load_config(z_cfg.config, list(z_cfg.overrides))
        zl = stack.enter_context(zenoh_link.ZenohAllocatorLink(z_cfg.vessel, conf))
        ports.setpoints.append(zl.setpoints)
        ports.telemetry.append(zl.odometry)
        ports.status.append(ZenohStatusSink(zl))
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
