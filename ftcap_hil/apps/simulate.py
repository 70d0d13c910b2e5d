"""Run a scenario offline: nominal controller -> allocator core -> faulty thrusters -> plant.

Writes DIR/<mode>/timeseries.csv, DIR/results.json and the PNG plots (with ``--mcap`` also
DIR/<mode>/run.mcap, docs/ros2-and-foxglove.md). The `none` run (no
faults) is always included: it is the reference for the deviation metrics.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
from pathlib import Path

from ftcap_hil.config.scenario import load_scenario, shipped_scenarios
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.models.plants import Inversion, SurfaceVessel
from ftcap_hil.core.models.vessel3dof import Vessel3DOF
from ftcap_hil.core.scenario import Integrator, Scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.report.summary import offline_summary_lines

log = logging.getLogger(__name__)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "scenario", help=f"a TOML file or a shipped scenario: {', '.join(shipped_scenarios())}"
    )
    group = p.add_mutually_exclusive_group()
    group.add_argument(
        "--mode", choices=[m.value for m in Mode], help="one mode (plus the none reference)"
    )
    group.add_argument("--compare", action="store_true", help="all modes (the default)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument(
        "--integrator",
        choices=[i.value for i in Integrator],
        help="override the scenario's true plant",
    )
    p.add_argument(
        "--inversion",
        choices=[i.value for i in Inversion],
        help="vessel: how the estimator inverts a step",
    )
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument(
        "--mcap", action="store_true", help="also DIR/<mode>/run.mcap (ROS 2 messages, Foxglove)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _scenario(args: argparse.Namespace) -> Scenario:
    """The scenario with the command line's overrides; ConfigError naming what is wrong."""
    try:
        sc = load_scenario(args.scenario)
        if args.integrator:
            sc = dataclasses.replace(sc, integrator=Integrator(args.integrator))
        if args.inversion:
            if not isinstance(sc.plant, SurfaceVessel | Vessel3DOF):
                raise ConfigError("--inversion applies to the vessel plant only")
            plant = dataclasses.replace(sc.plant, inversion=Inversion(args.inversion))
            sc = dataclasses.replace(sc, plant=plant)
    except ConfigError:
        raise
    except ValueError as e:
        raise ConfigError(str(e)) from e
    return sc


def run(args: argparse.Namespace) -> int:
    """Fly the scenario offline in the modes asked for; write results (and plots)."""
    from ftcap_hil.runtime.offline import run_modes

    sc = _scenario(args)
    modes = [Mode.NONE, Mode(args.mode)] if args.mode else list(Mode)
    modes = list(dict.fromkeys(modes))
    records = run_modes(sc, modes, progress=not args.quiet and sys.stderr.isatty())
    from ftcap_hil.report.records import write_results

    res = write_results(records, args.out)
    if not args.no_plots:
        from ftcap_hil.report.plots import write_plots

        write_plots(records, args.out)
    if args.mcap:
        from ftcap_hil.report.recording import write_recordings

        write_recordings(records, args.out)
    for line in offline_summary_lines(res):
        print(line)
    print(
        f"wrote {args.out}/results.json, {len(records)} timeseries.csv"
        + ("" if args.no_plots else " and plots")
        + (", run.mcap beside each" if args.mcap else "")
    )
    return 0
