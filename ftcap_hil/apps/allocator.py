"""Run the allocator daemon: setpoints and telemetry in (MAVLink, Zenoh), thrusters out (CAN).

Configuration: ``--config FILE`` (default: the shipped ftcap_hil/data/hil/allocator.toml) and
``--set SECTION.KEY=VALUE`` overrides. SIGINT/SIGTERM: a zero command, then exit 0; a second
one while stopping: the zero, then exit 130.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import time
from pathlib import Path

from ftcap_hil.apps.allocator_ports import build_ports
from ftcap_hil.apps.options import add_set_option
from ftcap_hil.config.daemon import LoadedConfig, load_daemon_config
from ftcap_hil.core.errors import ConfigError, FtcapError, PortError
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.command_log import CommandLog
from ftcap_hil.runtime.daemon import AllocatorDaemon
from ftcap_hil.runtime.drive_evidence import diagnosis_line
from ftcap_hil.runtime.param_sync import ParamSync

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", type=Path, help="daemon TOML (default: shipped allocator.toml)")
    p.add_argument(
        "--scenario",
        help="a realistic scenario (file or name): the vessel, its drives, sensor and sea as "
        "the offline simulator tells the allocator, in place of the file's [vessel] and [plant]",
    )
    add_set_option(p, "config", "daemon.rate_hz=10")
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument(
        "--command-log", type=Path, help="CSV of every command sent (monotonic ns, u_1..u_m in N)"
    )


def wire(
    cfg: LoadedConfig, stack: contextlib.ExitStack, command_log: Path | None = None
) -> AllocatorDaemon:
    """Open the ports ``cfg`` names (closed by ``stack``) and build the daemon on them, its
    parameters kept in step with the MAVLink table. Start-up failures raise ConfigError
    (a value the bridges refuse) or PortError (a port that cannot open)."""
    cmd_log = None
    if command_log is not None:
        cmd_log = CommandLog(command_log, cfg.daemon.thrusters.m)
        stack.callback(cmd_log.close)
    try:
        ports, params = build_ports(cfg, stack, cmd_log)
    except FtcapError:
        raise
    except (ValueError, TypeError) as e:
        raise ConfigError(f"start-up failed: {e}") from e
    except (RuntimeError, OSError) as e:
        raise PortError(f"start-up failed: {e}") from e
    daemon = AllocatorDaemon(cfg.daemon, ports)
    if params is not None:
        daemon.before_cycle.append(ParamSync(daemon, params))
        params.set_running(True)
    return daemon


def _load(args: argparse.Namespace) -> LoadedConfig:
    try:
        return load_daemon_config(args.config, args.set, getattr(args, "scenario", None))
    except FtcapError:
        raise
    except ValueError as e:
        raise ConfigError(str(e)) from e


def _log_summary(daemon: AllocatorDaemon) -> None:
    for line in daemon.latency.summary_lines():
        log.info("%s", line)
    log.info(
        "allocator: stopped after %d cycles, %d overruns, %d commands refused by the bus, "
        "%d malformed inputs dropped (%d of them implausible telemetry)",
        daemon.cycles,
        daemon.overruns,
        daemon.not_sent,
        daemon.malformed,
        daemon.sampler.gate.rejected,
    )


def _judged_by(cfg: LoadedConfig, daemon: AllocatorDaemon) -> str:
    """How the thrusters are judged, and why not by their drives if not."""
    c = cfg.daemon
    why = (
        f"mode {c.core.mode.value} has no estimation"
        if c.core.mode is not Mode.FTCAP
        else "[diagnosis] enabled = false"
    )
    return diagnosis_line(c.drives, daemon.drive.diagnosing, daemon.ports.esc_reports, why)


def run(args: argparse.Namespace) -> int:
    """Load, wire, run until stopped; the exit code (errors raise, see core/errors.py)."""
    cfg = _load(args)
    with contextlib.ExitStack() as stack:
        daemon = wire(cfg, stack, args.command_log)
        if args.duration:
            stop_at = time.monotonic() + args.duration
            daemon.before_cycle.append(
                lambda: daemon.request_exit() if time.monotonic() > stop_at else None
            )
        log.info(
            "allocator: %s, %.1f Hz, %d thrusters, mode %s, %d setpoint / %d telemetry ports"
            " (+%d unauthenticated)",
            cfg.source,
            cfg.daemon.rate_hz,
            cfg.daemon.thrusters.m,
            cfg.daemon.core.mode.value,
            len(daemon.ports.setpoints),
            len(daemon.ports.telemetry),
            len(daemon.ports.untrusted_telemetry),
        )
        log.info("allocator: %s", _judged_by(cfg, daemon))
        try:
            return daemon.run()
        finally:
            _log_summary(daemon)
