"""Start the CAN hub, the simulated vessel, the allocator and the ground station on loopback,
fly example 1 of the paper, print the results, stop everything.

Each part is a separate process (``ftcap-hil can-hub``, ``ftcap-hil allocator``,
``ftcap-hil sim``, ``ftcap-hil gcs``), all on 127.0.0.1 with free ports picked at start (UDP
for MAVLink, TCP for the CAN hub and the Zenoh router), so a demo never collides with another
setup on the default ports; with ``--ros2`` the router is on 7447, where rmw_zenoh's nodes
look for it, and the allocator and vessel are also on ROS 2 topics. ``--mcap``: the ground
station also writes DIR/<mode>/run.mcap. Logs: DIR/logs/<name>.log; PIDs: DIR/logs/pids.json.

Which mission: without ``--duration`` and ``--mission``, ``paper-4.2-ex1-short`` (example 1
with the schedule compressed: faults at 12 s and 45 s, 140 s); with ``--duration S``, the
paper's ``paper-4.2-ex1`` flown for S seconds (``--duration 700`` is the whole mission);
``--mission`` picks any mission (shipped name or file). Why a compressed schedule and no
speed-up: the vessel could run faster than real time (``sim.realtime_factor``), but the
allocator's loop rate, estimation period, per-second rate limits and timeouts and the ground
station's T_s and mission clock are all wall-clock and would all have to be scaled together;
a compressed schedule keeps every timing as on the real vessel.

Stopping: SIGTERM to each child still running, newest first, then SIGKILL after a grace
period; also on Ctrl-C, on SIGTERM and when any child dies early. A second Ctrl-C or SIGTERM
while stopping skips the grace period (SIGKILL at once). Exit code: 0 if every child ended
cleanly and the ground station flew the mission, 1 otherwise, 2 for a bad command line or
mission, 130 if interrupted.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ftcap_hil.core.errors import ConfigError
from ftcap_hil.runtime.loop import DeadlineLoop
from ftcap_hil.runtime.processes import (
    LOCALHOST,
    Child,
    Supervisor,
    free_ports,
    ftcap_argv,
    start_can_hub,
)
from ftcap_hil.runtime.signals import SignalCapture, capture_signals

log = logging.getLogger(__name__)

DEFAULT_MISSION = "paper-4.2-ex1-short"
PAPER_MISSION = "paper-4.2-ex1"
STOP_GRACE_S = 8.0
HUB_TIMEOUT_S = 15.0
ROS2_ROUTER_PORT = 7447  # rmw_zenoh's default router endpoint, tcp/localhost:7447
SUPERVISE_PERIOD_NS = 200_000_000


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, help="output folder (default: ftcap-runs/demo-<time>)")
    p.add_argument(
        "--duration",
        type=float,
        help=f"fly {PAPER_MISSION} for this many seconds (700 = the paper's whole mission);"
        f" default: {DEFAULT_MISSION} (140 s)",
    )
    p.add_argument("--mission", help="a mission file or shipped name (see `ftcap-hil gcs -h`)")
    p.add_argument(
        "--scenario",
        help="fly a realistic scenario (file or shipped name, e.g. cybership2-station): the "
        "vessel runs its truth and faults, the allocator is told it; verdict against offline",
    )
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="with --scenario: sim seconds per wall second (vessel, allocator and ground "
        "station scaled together)",
    )
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument(
        "--mcap", action="store_true", help="also DIR/<mode>/run.mcap (ROS 2 messages, Foxglove)"
    )
    p.add_argument(
        "--ros2",
        action="store_true",
        help=f"allocator and vessel also on ROS 2 topics (rmw_zenoh), router on port "
        f"{ROS2_ROUTER_PORT}",
    )


@dataclass(frozen=True)
class Ports:
    gcs: int
    allocator: int
    vessel: int
    zenoh: int
    can: int = 0  # known once the hub is up

    @classmethod
    def pick(cls) -> Ports:
        gcs, allocator, vessel = free_ports(socket.SOCK_DGRAM, 3)
        return cls(gcs, allocator, vessel, free_ports(socket.SOCK_STREAM, 1)[0])


def scenario_argv(role: str, scenario: str | None, speed: float, out: Path) -> list[str]:
    """What each process adds to fly a realistic scenario at ``speed`` x real time."""
    if scenario is None:
        return []
    sets = {
        "allocator": [f"daemon.time_scale={speed!r}"],
        "sim": ["sim.hold=true", f"sim.realtime_factor={speed!r}"],
        "gcs": [f"gcs.time_scale={speed!r}"],
    }[role]
    extra = ["--record", str(out / "vessel.csv")] if role == "sim" else []
    return ["--scenario", scenario, *extra, *[a for s in sets for a in ("--set", s)]]


def allocator_argv(p: Ports, ros2: bool = False) -> list[str]:
    zenoh_listen = f"['listen/endpoints:[\"tcp/{LOCALHOST}:{p.zenoh}\"]']"
    sets = [
        f"can.channel={LOCALHOST}:{p.can}",
        f"mavlink.connection=udpin:{LOCALHOST}:{p.allocator}",
        f'mavlink.peers=["{LOCALHOST}:{p.gcs}"]',
        f'mavlink.relay=["{LOCALHOST}:{p.vessel}"]',  # a ground station on one link sees both
        f"zenoh.overrides={zenoh_listen}",
        *(["zenoh.ros2=true"] if ros2 else []),
    ]
    return ftcap_argv("allocator", *[a for s in sets for a in ("--set", s)])


def vessel_argv(p: Ports, ros2: bool = False) -> list[str]:
    sets = [
        f"can.channel={LOCALHOST}:{p.can}",
        f"mavlink.connection=udpin:{LOCALHOST}:{p.vessel}",
        f'mavlink.peers=["{LOCALHOST}:{p.allocator}", "{LOCALHOST}:{p.gcs}"]',
        f"zenoh.connect=tcp/{LOCALHOST}:{p.zenoh}",
        *(["zenoh.ros2=true"] if ros2 else []),
    ]
    return ftcap_argv("sim", *[a for s in sets for a in ("--set", s)])


def gcs_argv(
    p: Ports, mission: str, out: Path, duration: float | None, plots: bool, mcap: bool = False
) -> list[str]:
    argv = ftcap_argv(
        "gcs",
        "--mission",
        mission,
        "--out",
        str(out),
        "--gcs-port",
        str(p.gcs),
        "--allocator-port",
        str(p.allocator),
        "--vessel-port",
        str(p.vessel),
    )
    if duration is not None:
        argv += ["--duration", repr(duration)]
    argv += ["--progress"]  # the demo echoes its progress lines (ProgressTail)
    return argv + ([] if plots else ["--no-plots"]) + (["--mcap"] if mcap else [])


class Interrupted(Exception):
    """A stop signal arrived: the demo stops its children and exits 130."""


class StopRequest:
    """A stop asked for by SIGINT / SIGTERM, acted on at the next safe point.

    The signal capture only takes note (its handlers never raise here: a second signal
    calls ``Supervisor.hurry``), so that a signal can never land between starting a child
    and recording it, nor cut the clean-up short; ``check`` raises Interrupted."""

    def __init__(self, signals: SignalCapture) -> None:
        self._signals = signals

    def check(self) -> None:
        if self._signals.stopping:
            raise Interrupted(self._signals.signal_name)


class ProgressTail:
    """The ground station's progress lines (``gcs --progress``), echoed from its log file as
    they appear: what the demo shows while it flies, on a terminal or not."""

    PREFIX = "progress:"

    def __init__(self, path: Path | None) -> None:
        self.path, self._offset, self._partial = path, 0, ""

    def lines(self) -> list[str]:
        """The complete progress lines written since the last call."""
        if self.path is None or not self.path.exists():
            return []
        with open(self.path, errors="replace") as fh:
            fh.seek(self._offset)
            text = self._partial + fh.read()
            self._offset = fh.tell()
        *done, self._partial = text.split("\n")
        return [ln for ln in done if ln.startswith(self.PREFIX)]


def supervise(
    sup: Supervisor,
    gcs: Child,
    loop: DeadlineLoop,
    stop: StopRequest,
    budget_s: float,
) -> None:
    """Until the ground station ends (or a stop signal ends ``loop``); RuntimeError if
    another child dies first or the ground station overruns ``budget_s``. Echoes the ground
    station's progress lines."""
    started = time.monotonic()
    tail = ProgressTail(gcs.log_path)

    def tick(now_ns: int) -> None:
        if (dead := sup.died(exclude=gcs)) is not None:
            raise RuntimeError(
                f"{dead.name} (pid {dead.pid}) exited early with code "
                f"{dead.returncode}, see {dead.log_path}"
            )
        elapsed = time.monotonic() - started
        if elapsed > budget_s:
            raise RuntimeError(f"the ground station is still running after {elapsed:.0f} s")
        for line in tail.lines():
            print(f"demo: {line}", flush=True)

    loop.run(tick, until=lambda: not gcs.running())
    for line in tail.lines():
        print(f"demo: {line}", flush=True)
    stop.check()


def start_all(
    sup: Supervisor, stop: StopRequest, args: argparse.Namespace, mission: str, out: Path
) -> Child:
    _, channel = start_can_hub(sup.start, timeout_s=HUB_TIMEOUT_S, check=stop.check)
    ports = Ports.pick()
    hub_port = int(channel.rsplit(":", 1)[1])
    zenoh = ROS2_ROUTER_PORT if args.ros2 else ports.zenoh  # where rmw_zenoh looks by default
    ports = Ports(ports.gcs, ports.allocator, ports.vessel, zenoh, hub_port)
    log.info("ports on %s: %s", LOCALHOST, ports)
    sc, k = args.scenario, args.speed
    # the Zenoh router: first
    sup.start(
        "allocator", allocator_argv(ports, args.ros2) + scenario_argv("allocator", sc, k, out)
    )
    stop.check()
    sup.start("vessel", vessel_argv(ports, args.ros2) + scenario_argv("sim", sc, k, out))
    stop.check()
    argv = gcs_argv(ports, mission, out, args.duration, not args.no_plots, args.mcap)
    if sc is not None:  # the scenario in place of the mission
        i = argv.index("--mission")
        argv[i : i + 2] = scenario_argv("gcs", sc, k, out)
    return sup.start("gcs", argv)


def expected_duration(mission: str, duration: float | None, scenario: str | None = None) -> float:
    """The mission's (or ``scenario``'s) length in mission seconds, unless ``duration``."""
    if duration is not None:
        return duration
    if scenario is not None:
        from ftcap_hil.config.scenario import load_scenario

        return load_scenario(scenario).duration_s
    from ftcap_hil.config.mission import load_mission

    return load_mission(mission).duration_s


def scenario_verdict(
    flight: dict[str, Any], out: Path, scenario: str, duration_s: float
) -> list[str]:
    """A realistic flight against the offline run of the same scenario and seed, in the
    flight's mode (``report.hil_compare``; the vessel's record and the flight's flags)."""
    from dataclasses import replace

    from ftcap_hil.config.scenario import load_scenario
    from ftcap_hil.core.status import Mode
    from ftcap_hil.report.hil_compare import comparison_lines, live_metrics, offline_metrics
    from ftcap_hil.runtime.offline import run_mode

    mode = next(iter(flight["modes"]))
    gcs_csv, vessel_csv = out / mode / "timeseries.csv", out / "vessel.csv"
    if not (gcs_csv.exists() and vessel_csv.exists()):
        return [f"verdict: none (no {gcs_csv} or {vessel_csv})"]
    sc = replace(load_scenario(scenario), duration_s=duration_s)
    none, offline = run_mode(sc, Mode.NONE), run_mode(sc, Mode(mode))
    live = live_metrics(sc.faults, vessel_csv, gcs_csv, none)
    period = sc.estimation_period_s or sc.dt_s
    head = f"verdict ({mode} live over MAVLink/CAN against offline, {sc.name} seed {sc.seed}):"
    return [head, *comparison_lines(live, offline_metrics(offline, none), period)]


def print_summary(
    out: Path, wall_s: float, mission: str, duration_s: float, scenario: str | None = None
) -> None:
    from ftcap_hil.report.summary import flight_summary_lines as summary_lines

    path = out / "results.json"
    if not path.exists():
        print(f"demo: no {path} (see {out / 'logs' / 'gcs.log'})")
        return
    flight = json.loads(path.read_text())
    for line in summary_lines(flight):
        print(line)
    lines = (
        verdict(flight, mission, duration_s)
        if scenario is None
        else scenario_verdict(flight, out, scenario, duration_s)
    )
    for line in lines:
        print(line)
    plots = sorted(p.name for p in out.glob("*.png"))
    print(f"results: {path}; timeseries: {', '.join(str(p) for p in out.glob('*/timeseries.csv'))}")
    print(f"plots in {out}: {', '.join(plots) if plots else 'none'}")
    print(f"logs: {out / 'logs'}; wall time {wall_s:.1f} s")


def _fly(
    sup: Supervisor,
    loop: DeadlineLoop,
    stop: StopRequest,
    args: argparse.Namespace,
    mission: str,
    out: Path,
    expected_s: float,
) -> int:
    """Start everything, supervise, stop everything; the exit code before child failures."""
    try:
        print(f"demo: flying {mission} for {expected_s:.0f} s; logs in {out / 'logs'}", flush=True)
        gcs = start_all(sup, stop, args, mission, out)
        supervise(sup, gcs, loop, stop, budget_s=expected_s / args.speed + 120.0)
    except Interrupted as e:
        log.error("interrupted (%s): stopping everything", e)
        return 130
    except (RuntimeError, OSError) as e:
        log.error("%s", e)
        return 1
    finally:
        sup.stop_all()
    return 0


def verdict(flight: dict[str, Any], mission: str, duration_s: float) -> list[str]:
    """The verdict lines: the flight against an offline run of the same scenario (none, CAP,
    F-TCAP; about a second)."""
    from dataclasses import replace

    from ftcap_hil.config.mission import load_mission
    from ftcap_hil.core.status import Mode
    from ftcap_hil.report.records import results
    from ftcap_hil.report.summary import verdict_lines
    from ftcap_hil.runtime.offline import run_modes

    sc = replace(load_mission(mission).scenario, duration_s=duration_s)
    offline = results(run_modes(sc, [Mode.NONE, Mode.CAP, Mode.FTCAP]))
    if [list(p) for p in offline["phases"]] != [list(p) for p in flight["phases"]]:
        return [f"verdict: none (the flight's phases {flight['phases']} are not the scenario's)"]
    return verdict_lines(flight, offline)[0]


def run(args: argparse.Namespace) -> int:
    """Fly the demo; the exit code (module docstring)."""
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise ConfigError(f"--duration must be positive, got {args.duration}")
    if not (math.isfinite(args.speed) and args.speed > 0):
        raise ConfigError(f"--speed must be positive, got {args.speed}")
    if args.scenario is not None and args.mission is not None:
        raise ConfigError("--scenario and --mission: give one (the scenario is the mission)")
    if args.scenario is None and args.speed != 1.0:
        raise ConfigError("--speed needs --scenario (the paper's missions fly in real time)")
    mission = args.mission or (DEFAULT_MISSION if args.duration is None else PAPER_MISSION)
    mission = args.scenario or mission
    out = args.out or Path("ftcap-runs") / f"demo-{time.strftime('%Y%m%d-%H%M%S')}"
    try:
        expected = expected_duration(mission, args.duration, args.scenario)
    except ConfigError:
        raise
    except ValueError as e:
        raise ConfigError(str(e)) from e
    (out / "logs").mkdir(parents=True, exist_ok=True)
    # Ctrl-C reaches the demo only (new sessions): it stops the children
    sup = Supervisor(out / "logs", pids_file="pids.json", grace_s=STOP_GRACE_S, new_session=True)
    loop = DeadlineLoop(SUPERVISE_PERIOD_NS)
    started = time.monotonic()
    with capture_signals(loop.request_exit, on_force=sup.hurry) as signals:
        code = _fly(sup, loop, StopRequest(signals), args, mission, out, expected)
    for failure in sup.failures():
        log.error("child failed: %s", failure)
        code = code or 1
    print_summary(out, time.monotonic() - started, mission, expected, args.scenario)
    return code
