"""Run the simulated vessel: plant, ESCs on CAN, odometry out, fault injection in.

Configuration: the shipped ``ftcap_hil/data/hil/vessel.toml`` (or ``--config``) plus
``--set SECTION.KEY=VALUE``. SIGINT/SIGTERM end the run cleanly (exit 0; a second one: at
once, 130). ``--record FILE.csv`` writes one row per telemetry sample: true state, commands,
produced forces and true faults. A bad configuration exits 2, a port that cannot open 1.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
from pathlib import Path

from ftcap_hil.apps.options import add_set_option
from ftcap_hil.apps.vessel_ports import VesselPorts
from ftcap_hil.config.sim import load_config
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.runtime.command_log import open_new_record
from ftcap_hil.runtime.vessel_process import Recorder, VesselProcess

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", type=Path, help="vessel TOML (default: the shipped vessel.toml)")
    p.add_argument(
        "--scenario",
        help="a scenario (file or name): a realistic one is the truth (vessel, environment, "
        "drives, sensor, faults); a plain one gives the true faults",
    )
    add_set_option(p, "config", "sim.silent_thrusters=[2]")
    p.add_argument("--duration", type=float, help="stop after this many seconds of sim time")
    p.add_argument("--record", type=Path, help="write the true state and faults to this CSV")


def run(args: argparse.Namespace) -> int:
    """Load, open the ports, run until stopped; the exit code (errors raise ConfigError or
    PortError, see core/errors.py)."""
    if args.duration is not None and not args.duration > 0:
        raise ConfigError(f"--duration: expected a positive number of seconds, got {args.duration}")
    cfg = load_config(args.config, args.set, args.scenario)
    with contextlib.ExitStack() as stack:
        shell = cfg.shell
        ports = VesselPorts.open(
            cfg.ports, cfg.sim.thrusters, shell.fault_injection_enabled, shell.hold
        )
        stack.callback(ports.shutdown)
        recorder = None
        if args.record is not None:  # a record already there is kept aside, never truncated
            fh = stack.enter_context(open_new_record(args.record, "--record"))
            recorder = Recorder(fh, cfg.sim.thrusters)
        truth = "the paper's plant" if cfg.scenario is None else f"scenario {cfg.scenario.name}"
        log.info(
            "simulated vessel running (%s), %s, %d thrusters, %g x real time%s",
            cfg.source, truth, cfg.sim.thrusters.m, shell.realtime_factor,
            ", held at t = 0 until SIM_HOLD = 0" if shell.hold else "",
        )  # fmt: skip
        return VesselProcess(cfg, ports, recorder, args.duration).run()
