"""Ground-station script: fly a mission over MAVLink and record it like the offline simulator.

Start-up: wait for the HEARTBEATs of the vessel and the allocator, set the vessel's
SYS_FAILURE_EN = 1 (if the mission injects faults), set the allocator's FTC_MODE (if the
mission names a mode) and read it back, wait for the first ODOMETRY: mission time starts
there. Then, every T_s on absolute deadlines: the nominal law of eq. (24) on the latest
ODOMETRY -> WRENCH_SETPOINT, the mission's fault changes -> MAV_CMD_INJECT_FAILURE (sent
from a worker thread, so the loop never waits for an ACK), one recorded row. At the end:
zero wrench, faults cleared, then DIR/<mode>/timeseries.csv, DIR/results.json and the plots.

Recorded per cycle: the true faults from the mission's schedule; delta_hat, f_hat and the
DEGRADED flag from FTCAP_STATUS; u from ACTUATOR_OUTPUT_STATUS; v_ach = B (delta u + f) with
the truth; bf_hat = B f_hat. innovation, window_len, probing and solve_us are not on the
MAVLink status and are NaN. Exit codes: 0 done, 2 configuration, 3 vessel or allocator not
answering, 4 link lost mid-flight, 5 an injection was refused or not acknowledged,
1 interrupted (SIGINT / SIGTERM; the part flown is still written).
"""

from __future__ import annotations

import argparse
import enum
import logging
import math
import queue
import signal
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.config.mission import Mission, load_mission, shipped_missions
from ftcap_hil.core.controllers import limit_wrench
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.faults import Injection, injection_plan
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.report.flight import FlightRecorder
from ftcap_hil.report.records import RunRecord
from ftcap_hil.report.summary import flight_summary_lines as summary_lines

log = logging.getLogger(__name__)


class Exit(enum.IntEnum):
    OK = 0
    INTERRUPTED = 1  # SIGINT / SIGTERM
    CONFIG = 2
    NO_ANSWER = 3  # vessel or allocator silent at start-up
    LINK_LOST = 4  # no ODOMETRY mid-flight
    INJECTION = 5  # an injection refused or not acknowledged


class GcsError(RuntimeError):
    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--mission",
        required=True,
        help=f"a mission TOML or one of: {', '.join(shipped_missions())}",
    )
    p.add_argument("--out", type=Path, help="output folder (default: ftcap-runs/<mission>-<time>)")
    p.add_argument("--duration", type=float, help="mission seconds to fly (default: the mission's)")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override a mission value, e.g. --set mission.mode=cap --set gcs.wrench_limit=[1,1,1]",
    )
    p.add_argument("--gcs-port", type=int, default=14550, help="this script's UDP inbox")
    p.add_argument("--allocator-port", type=int, default=14570, help="the allocator's UDP inbox")
    p.add_argument("--vessel-port", type=int, default=14560, help="the vessel's UDP inbox")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")


# --- fault injection off the loop thread ---


@dataclass
class InjectionOutcome:
    injection: Injection
    sent_at_s: float
    result: str  # MavResult name, or "NO_ACK"

    @property
    def ok(self) -> bool:
        return self.result == "ACCEPTED"

    def as_dict(self) -> dict[str, Any]:
        i = self.injection
        value = None if math.isnan(i.value) else i.value
        keys = ("at_s", "sent_at_s", "thruster", "kind", "value", "result")
        return dict(
            zip(
                keys,
                (i.at_s, self.sent_at_s, i.thruster + 1, i.kind.name, value, self.result),
                strict=True,
            )
        )


class Injector:
    """Sends injections in order on its own thread; outcomes are drained by the loop."""

    def __init__(self, link: Any, t0_ns: int) -> None:
        self._link, self._t0_ns = link, t0_ns
        self._todo: queue.Queue[Injection | None] = queue.Queue()
        self.outcomes: queue.Queue[InjectionOutcome] = queue.Queue()
        self._thread = threading.Thread(target=self._run, name="gcs-injector", daemon=True)
        self._thread.start()

    def submit(self, items: list[Injection]) -> None:
        for item in items:
            self._todo.put(item)

    def _run(self) -> None:
        while (item := self._todo.get()) is not None:
            sent = (time.monotonic_ns() - self._t0_ns) * 1e-9
            result = self._link.inject_failure(item.kind, item.thruster, item.value)
            self.outcomes.put(
                InjectionOutcome(item, sent, "NO_ACK" if result is None else result.name)
            )

    def close(self, timeout_s: float = 10.0) -> None:
        self._todo.put(None)
        self._thread.join(timeout_s)


# --- live status on a terminal ---


class StatusLine:
    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self._shown = False

    def show(self, text: str) -> None:
        if self.enabled:
            sys.stderr.write("\r" + text + "\x1b[K")
            sys.stderr.flush()
            self._shown = True

    def clear(self) -> None:
        if self._shown:
            sys.stderr.write("\r\x1b[K")
            sys.stderr.flush()
            self._shown = False


def status_text(t: float, duration: float, x: FloatArray, ref: FloatArray, st: Any, u: Any) -> str:
    err = math.hypot(x[0] - ref[0], x[1] - ref[1])
    dh = " ".join(f"{d:.2f}" for d in st.delta_hat) if st is not None else "-"
    thrust = " ".join(f"{v:+.3f}" for v in u) if u is not None else "-"
    return (
        f"t {t:6.1f}/{duration:.0f} s  N {x[0]:+6.2f} E {x[1]:+6.2f} m"
        f"  psi {math.degrees(x[2]):+7.1f} deg  |e| {err:5.2f} m  dhat {dh}  u {thrust} N"
    )


# --- the flight ---


@dataclass
class Flight:
    mission: Mission
    link: Any
    t0_ns: int
    recorder: FlightRecorder
    line: StatusLine
    cycles: int = 0
    overruns: int = 0
    limited_cycles: int = 0
    outcomes: list[InjectionOutcome] = field(default_factory=list)
    should_exit: bool = False
    _wake: threading.Event = field(default_factory=threading.Event)
    _flags: dict[str, bool] = field(default_factory=dict)

    def request_exit(self, *_: object) -> None:
        self.should_exit = True
        self._wake.set()

    def _say(self, level: int, msg: str, *args: Any) -> None:
        self.line.clear()
        log.log(level, msg, *args)

    def meta(self, started: float) -> dict[str, Any]:
        """Extra results.json entries for this run (JSON-ready)."""
        return {
            "source": "ftcap-hil gcs (MAVLink HIL)",
            "mission": self.mission.name,
            "cycles": self.cycles,
            "overruns": self.overruns,
            "wrench_limited_cycles": self.limited_cycles,
            "wall_time_s": time.monotonic() - started,
            "injections": [o.as_dict() for o in self.outcomes],
            "not_on_mavlink": ["innovation", "window_len", "probing", "solve_us"],
        }

    def _transition(self, name: str, on: bool, text: str) -> None:
        """Log a condition when it starts and when it ends, not every cycle."""
        if on != self._flags.get(name, False):
            self._flags[name] = on
            self._say(logging.WARNING if on else logging.INFO, "%s%s", "" if on else "over: ", text)

    def drain(self, injector: Injector) -> None:
        while not injector.outcomes.empty():
            out = injector.outcomes.get_nowait()
            self.outcomes.append(out)
            i = out.injection
            what = f"inject {i.kind.name} on thruster {i.thruster + 1} (value {i.value:g})"
            level = logging.INFO if out.ok else logging.ERROR
            self._say(level, "t = %.2f s: %s: %s", out.sent_at_s, what, out.result)
        for item in self.link.drain_statustexts():
            text = item.value
            self._say(logging.INFO, "STATUSTEXT %d/%d: %s", text.system, text.component, text.text)

    def cycle(self, now_ns: int, injector: Injector, plan: deque[Injection]) -> None:
        sc, t = self.mission.scenario, (now_ns - self.t0_ns) * 1e-9
        odom = self.link.odometry.latest()
        age_s = (now_ns - odom.stamp_ns) * 1e-9
        if age_s > self.mission.gcs.odometry_timeout_s:
            raise GcsError(
                f"no ODOMETRY from the vessel for {age_s:.1f} s (t = {t:.1f} s)", Exit.LINK_LOST
            )
        due = []
        while plan and plan[0].at_s <= t:
            due.append(plan.popleft())
        injector.submit(due)
        x = np.concatenate([odom.value.eta, odom.value.nu])
        ref = sc.reference_at(t)
        law = sc.controller(x, ref)
        v = limit_wrench(law, self.mission.gcs.wrench_limit)
        self.limited_cycles += int(v is not law)
        self._transition("limit", v is not law, "demand beyond gcs.wrench_limit: shrunk")
        self.link.send_wrench(v)
        st, cmd = self.link.allocator_status.latest(), self.link.thruster_commands.latest()
        silent = st is None or (now_ns - st.stamp_ns) * 1e-9 > 2.0
        self._transition("allocator", silent and t > 2.0, "no FTCAP_STATUS from the allocator")
        st_v = None if st is None else st.value
        u = None if cmd is None else cmd.value.u
        self.recorder.add(t, x, ref, v, st_v, u)
        self.line.show(status_text(t, self.mission.duration_s, x, ref, st_v, u))
        self.drain(injector)
        self.cycles += 1

    def run(self, injector: Injector) -> None:
        period_ns = int(self.mission.period_s * 1e9)
        end_ns = self.t0_ns + int(self.mission.duration_s * 1e9)
        plan = deque(injection_plan(self.mission.scenario.faults, self.mission.duration_s))
        deadline = self.t0_ns
        while not self.should_exit:
            now = time.monotonic_ns()
            if now >= end_ns:
                break
            self.cycle(now, injector, plan)
            deadline += period_ns
            late = time.monotonic_ns() - deadline
            if late > 0:  # skip the deadlines this cycle ran past, keep the phase
                missed = late // period_ns + 1
                self.overruns += int(missed)
                deadline += int(missed) * period_ns
            self._wake.wait(max(0.0, (min(deadline, end_ns) - time.monotonic_ns()) * 1e-9))
        self.line.clear()


# --- start-up and shut-down over MAVLink ---


def connect(link: Any, mission: Mission, inject: bool) -> tuple[str, int]:
    """Heartbeats, allocator loop running, SYS_FAILURE_EN, FTC_MODE, first ODOMETRY
    -> (mode name, t0 stamp)."""
    from bridges.mavlink.allocator_params import CODE_OF_MODE, MODE_CODES
    from bridges.mavlink.vessel import FAILURE_ENABLE_PARAM

    timeout = mission.gcs.connect_timeout_s
    for name, ids in (("vessel", link.vessel_ids), ("allocator", link.allocator_ids)):
        if not link.wait_heartbeat(ids, timeout):
            raise GcsError(
                f"no HEARTBEAT from the {name} {ids} within {timeout:g} s: is it "
                "running, and on the expected UDP port?",
                Exit.NO_ANSWER,
            )
    if not link.wait_ready(link.allocator_ids, timeout):
        raise GcsError(
            f"the allocator {link.allocator_ids} still reports MAV_STATE_BOOT after "
            f"{timeout:g} s: its control loop has not started (see its log)",
            Exit.NO_ANSWER,
        )
    if inject and link.set_param(link.vessel_ids, FAILURE_ENABLE_PARAM, 1) != 1:
        raise GcsError(f"the vessel did not accept {FAILURE_ENABLE_PARAM} = 1", Exit.NO_ANSWER)
    if mission.mode is not None:
        code = CODE_OF_MODE[mission.mode]
        if link.set_param(link.allocator_ids, "FTC_MODE", code) != code:
            raise GcsError(f"the allocator refused FTC_MODE = {code}", Exit.NO_ANSWER)
    params = link.fetch_params(link.allocator_ids, timeout_s=min(timeout, 5.0))
    if "FTC_MODE" not in params:
        raise GcsError("the allocator did not report FTC_MODE (parameter protocol)", Exit.NO_ANSWER)
    mode = MODE_CODES[int(params["FTC_MODE"])].value
    deadline = time.monotonic() + timeout
    while (first := link.odometry.latest()) is None:
        if time.monotonic() > deadline:
            raise GcsError(f"no ODOMETRY from the vessel within {timeout:g} s", Exit.NO_ANSWER)
        time.sleep(0.01)
    return mode, first.stamp_ns


def wind_down(link: Any, inject: bool, clear: bool) -> None:
    link.send_wrench([0.0, 0.0, 0.0])
    if inject and clear:
        from ftcap_hil.core.messages import FaultKind

        result = link.inject_failure(FaultKind.OK, None)
        log.info("faults cleared on the vessel: %s", "NO_ACK" if result is None else result.name)


def write_outputs(rec: RunRecord, out: Path, plots: bool) -> dict[str, Any]:
    from ftcap_hil.report.records import write_results

    res = write_results({rec.mode: rec}, out)
    if plots and len(rec.t) > 1:
        from ftcap_hil.report.plots import write_plots

        write_plots({rec.mode: rec}, out)
    return res


def _default_out(mission: Mission) -> Path:
    return Path("ftcap-runs") / f"{mission.name}-{time.strftime('%Y%m%d-%H%M%S')}"


def _endpoint(args: argparse.Namespace) -> Any:
    from bridges.mavlink.config import GCS_IDS, MavlinkEndpoint

    return MavlinkEndpoint.inbox(args.gcs_port, GCS_IDS, (args.allocator_port, args.vessel_port))


def fly_mission(args: argparse.Namespace, mission: Mission, out: Path) -> int:
    from bridges.mavlink.gcs import MavlinkGcsLink

    inject = bool(injection_plan(mission.scenario.faults, mission.duration_s))
    started = time.monotonic()
    with MavlinkGcsLink(_endpoint(args)) as link:
        mode, t0_ns = connect(link, mission, inject)
        log.info(
            "flying %s (%s) for %.1f s, allocator mode %s, T_s %.4f s",
            mission.name,
            mission.source,
            mission.duration_s,
            mode,
            mission.period_s,
        )
        flight = Flight(
            mission, link, t0_ns, FlightRecorder(mission.scenario), StatusLine(sys.stderr.isatty())
        )
        injector = Injector(link, t0_ns)
        saved = {s: signal.signal(s, flight.request_exit) for s in (signal.SIGINT, signal.SIGTERM)}
        error: GcsError | None = None
        try:
            flight.run(injector)
        except GcsError as e:
            error = e
        finally:
            for sig, handler in saved.items():
                signal.signal(sig, handler)
            injector.close()
            flight.drain(injector)
            wind_down(link, inject, mission.gcs.clear_faults_at_end)
    rec = flight.recorder.finish(mode, mission.period_s, **flight.meta(started))
    res = write_outputs(rec, out, not args.no_plots)
    for line in summary_lines(res):
        print(line)
    print(
        f"wrote {out}/results.json, {out}/{mode}/timeseries.csv"
        + ("" if args.no_plots else " and plots")
    )
    return _exit_code(flight, error)


def _exit_code(flight: Flight, error: GcsError | None) -> int:
    if error is not None:
        log.error("%s", error)
        return error.code
    if flight.should_exit:
        log.error("interrupted after %d cycles; the part flown was written", flight.cycles)
        return Exit.INTERRUPTED
    bad = [o for o in flight.outcomes if not o.ok]
    if bad:
        log.error("%d fault injection(s) failed: %s", len(bad), [o.as_dict() for o in bad])
        return Exit.INJECTION
    return Exit.OK


def run(args: argparse.Namespace) -> int:
    try:
        mission = load_mission(args.mission, args.set)
        if args.duration is not None:
            mission = mission.with_duration(args.duration)
        for key in ("gcs_port", "allocator_port", "vessel_port"):
            if not 0 < getattr(args, key) < 65536:
                raise ConfigError(f"--{key.replace('_', '-')}: {getattr(args, key)} is no UDP port")
    except (ConfigError, ValueError) as e:
        print(f"ftcap-hil gcs: {e}", file=sys.stderr)
        return Exit.CONFIG
    out = args.out or _default_out(mission)
    try:
        return fly_mission(args, mission, out)
    except GcsError as e:
        print(f"ftcap-hil gcs: {e}", file=sys.stderr)
        return e.code
    except KeyboardInterrupt:
        print("ftcap-hil gcs: interrupted before the flight started", file=sys.stderr)
        return Exit.INTERRUPTED
