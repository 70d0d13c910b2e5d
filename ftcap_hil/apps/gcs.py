"""Ground-station script: fly a mission over MAVLink and record it like the offline simulator.

The wiring of :mod:`ftcap_hil.runtime.ground_station` for one mission. Start-up: wait for
the HEARTBEATs of the vessel and the allocator (its loop past MAV_STATE_BOOT), set the
vessel's SYS_FAILURE_EN = 1 (if the mission injects faults), set the allocator's FTC_MODE
(if the mission names a mode) and read it back, wait for the first ODOMETRY: mission time
starts there. Then, every T_s on absolute deadlines: the nominal law of eq. (24) on the
latest ODOMETRY -> WRENCH_SETPOINT, the mission's fault changes -> MAV_CMD_INJECT_FAILURE
(sent from a worker thread, so the loop never waits for an ACK), one recorded row. At the
end: zero wrench, faults cleared, then DIR/<mode>/timeseries.csv, DIR/results.json and the
plots.

Recorded per cycle: the true faults from the mission's schedule; delta_hat, f_hat,
delta_std, the faulty flags and the DEGRADED flag from FTCAP_STATUS; u from
ACTUATOR_OUTPUT_STATUS; v_ach = B (delta u + f) with the truth; bf_hat = B f_hat. The columns
the MAVLink status does not carry (``report.flight.NOT_ON_MAVLINK``) are NaN. Exit codes (the
shared table, ``ftcap_hil.core.errors``): 0 done, 2 configuration, 3 vessel or allocator not
answering, 4 link lost mid-flight, 5 an injection or a parameter refused or not acknowledged,
130 interrupted (SIGINT / SIGTERM; a flight stopped by the first signal is still written).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path
from typing import Any

from ftcap_hil.apps.options import add_set_option
from ftcap_hil.config.mission import (
    Mission,
    load_mission,
    scenario_mission,
    shipped_missions,
)
from ftcap_hil.core.errors import ConfigError, ExitCode, FtcapError
from ftcap_hil.report.flight import NOT_ON_MAVLINK, FlightRecorder
from ftcap_hil.report.records import RunRecord
from ftcap_hil.report.summary import flight_summary_lines as summary_lines
from ftcap_hil.runtime.ground_station import (
    Flight,
    GroundStation,
    GroundStationError,
    ProgressLine,
    StatusLine,
    flight_plan,
)
from ftcap_hil.runtime.signals import capture_signals

log = logging.getLogger(__name__)

PROGRESS_EVERY_S = 5.0  # --progress: a line this often (mission time)


def add_arguments(p: argparse.ArgumentParser) -> None:
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument(
        "--mission",
        help=f"a mission TOML or one of: {', '.join(shipped_missions())}",
    )
    which.add_argument(
        "--scenario",
        help="a realistic scenario the vessel runs (sim --scenario, held): released at the "
        "start, flown on the vessel's clock, no injections",
    )
    p.add_argument("--out", type=Path, help="output folder (default: ftcap-runs/<mission>-<time>)")
    p.add_argument("--duration", type=float, help="mission seconds to fly (default: the mission's)")
    add_set_option(p, "mission", "mission.mode=cap")
    p.add_argument("--gcs-port", type=int, default=14550, help="this script's UDP inbox")
    p.add_argument("--allocator-port", type=int, default=14570, help="the allocator's UDP inbox")
    p.add_argument("--vessel-port", type=int, default=14560, help="the vessel's UDP inbox")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument(
        "--mcap", action="store_true", help="also DIR/<mode>/run.mcap (ROS 2 messages, Foxglove)"
    )
    p.add_argument(
        "--progress",
        action="store_true",
        help=f"a progress line on stdout every {PROGRESS_EVERY_S:g} s of mission time (time, "
        "phase, injections, the allocator's verdict)",
    )


def write_outputs(rec: RunRecord, out: Path, plots: bool, mcap: bool = False) -> dict[str, Any]:
    """results.json and timeseries.csv, the plots if ``plots``, run.mcap if ``mcap``."""
    from ftcap_hil.report.records import write_results

    res = write_results({rec.mode: rec}, out)
    if plots and len(rec.t) > 1:
        from ftcap_hil.report.plots import write_plots

        write_plots({rec.mode: rec}, out)
    if mcap:
        from ftcap_hil.report.recording import write_recordings

        write_recordings({rec.mode: rec}, out)
    return res


def _default_out(mission: Mission) -> Path:
    return Path("ftcap-runs") / f"{mission.name}-{time.strftime('%Y%m%d-%H%M%S')}"


def _endpoint(args: argparse.Namespace) -> Any:
    from bridges.mavlink.config import GCS_IDS, MavlinkEndpoint

    return MavlinkEndpoint.inbox(args.gcs_port, GCS_IDS, (args.allocator_port, args.vessel_port))


def meta(mission: Mission, flight: Flight, started: float) -> dict[str, Any]:
    """Extra results.json entries for this run (JSON-ready)."""
    return {
        "source": "ftcap-hil gcs (MAVLink HIL)",
        "mission": mission.name,
        "cycles": flight.cycles,
        "overruns": flight.overruns,
        "wrench_limited_cycles": flight.limited_cycles,
        "wall_time_s": time.monotonic() - started,
        "injections": [o.as_dict() for o in flight.outcomes],
        "not_on_mavlink": list(NOT_ON_MAVLINK),
    }


def fly_mission(args: argparse.Namespace, mission: Mission, out: Path) -> int:
    """Connect, fly, wind down, write the record; the exit code."""
    from bridges.mavlink.gcs import MavlinkGcsLink

    plan = flight_plan(mission)
    inject = bool(plan.injections)
    started = time.monotonic()
    error: GroundStationError | None = None
    with MavlinkGcsLink(_endpoint(args)) as link:
        station = GroundStation(link)
        with capture_signals(station.request_exit) as signals:
            held = mission.gcs.time_scale if mission.gcs.vessel_clock else None
            conn = station.connect(
                mission.gcs.connect_timeout_s, enable_failures=inject, mode=mission.mode,
                release=held,
            )  # fmt: skip
            mode = conn.mode or "unknown"
            log.info(
                "flying %s (%s) for %.1f s, allocator mode %s, T_s %.4f s",
                mission.name, mission.source, mission.duration_s, mode, mission.period_s,
            )  # fmt: skip
            recorder = FlightRecorder(mission.scenario)
            progress = None
            if args.progress:
                sc = mission.scenario
                progress = ProgressLine(
                    PROGRESS_EVERY_S, sc.phases(), mission.duration_s, mode=conn.mode
                )
            live = StatusLine(sys.stderr.isatty())
            flight = station.flight(plan, conn.t0_ns, recorder, live, progress)
            try:
                flight.run()
            except GroundStationError as e:
                error = e
            finally:
                station.wind_down(inject and mission.gcs.clear_faults_at_end)
    rec = recorder.finish(mode, mission.period_s, **meta(mission, flight, started))
    res = write_outputs(rec, out, not args.no_plots, args.mcap)
    for line in summary_lines(res):
        print(line)
    print(
        f"wrote {out}/results.json, {out}/{mode}/timeseries.csv"
        + ("" if args.no_plots else " and plots")
        + (f", {out}/{mode}/run.mcap" if args.mcap else "")
    )
    return _exit_code(flight, error, signals.stopping)


def _exit_code(flight: Flight, error: GroundStationError | None, interrupted: bool) -> int:
    if error is not None:
        log.error("%s", error)
        return error.exit_code
    if interrupted:
        log.error("interrupted after %d cycles; the part flown was written", flight.cycles)
        return ExitCode.INTERRUPTED
    bad = [o for o in flight.outcomes if not o.ok]
    if bad:
        log.error("%d fault injection(s) failed: %s", len(bad), [o.as_dict() for o in bad])
        return ExitCode.REFUSED
    return ExitCode.OK


def run(args: argparse.Namespace) -> int:
    try:
        if args.mission is not None:
            mission = load_mission(args.mission, args.set)
        else:
            mission = scenario_mission(args.scenario, args.set)
        if args.duration is not None:
            mission = mission.with_duration(args.duration)
        for key in ("gcs_port", "allocator_port", "vessel_port"):
            if not 0 < getattr(args, key) < 65536:
                raise ConfigError(f"--{key.replace('_', '-')}: {getattr(args, key)} is no UDP port")
    except (ConfigError, ValueError) as e:
        print(f"ftcap-hil gcs: {e}", file=sys.stderr)
        return ExitCode.CONFIG
    out = args.out or _default_out(mission)
    try:
        return fly_mission(args, mission, out)
    except FtcapError as e:  # no answer, refused, interrupted at start-up, a port failing
        print(f"ftcap-hil gcs: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:  # a second signal: stopped at once, nothing written
        print("ftcap-hil gcs: interrupted", file=sys.stderr)
        return ExitCode.INTERRUPTED
