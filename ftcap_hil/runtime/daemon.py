"""The allocator daemon's loop: startup -> cycles on absolute deadlines -> shutdown.

One thread (the caller of ``run``) owns the core. Bridges only fill mailboxes; the loop
reads the latest values with their ages. A cycle runs at every deadline of the fixed rate,
and also as soon as a new setpoint arrives (``wake_on_setpoint``: the latency from a
setpoint to a thruster frame is then one cycle's work, not up to a period; the deadlines
keep their phase). Each cycle:

    setpoint (+ age) -> watchdog -> estimation sample from telemetry -> core.step
    -> thruster command on CAN -> transitions logged -> status (decimated)

Watchdogs: no setpoint for ``setpoint_timeout_s`` -> zero thrust; telemetry older than
``telemetry_timeout_s`` -> estimation frozen, allocation continues; an ESC silent for
``esc_timeout_s`` -> that thruster allocated as failed. An ESC not heard yet is held at zero
too, but announced as waiting (info), not as failed, until another ESC has been reporting for
``esc_timeout_s``: at start-up the vessel may simply not be powered yet. On exit, always a
zero command.
"""

from __future__ import annotations

import logging
import math
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from ftcap_hil.core.allocator import AllocationStatus
from ftcap_hil.core.cycle import CoreConfig, CycleResult, FtcapCore
from ftcap_hil.core.estimation import Observation
from ftcap_hil.core.geometry import ThrusterSet
from ftcap_hil.core.messages import BoolArray, EscStatus, FloatArray, Odometry, WrenchSetpoint
from ftcap_hil.core.plants import SurfaceVessel
from ftcap_hil.core.status import AllocatorStatus, Mode, Severity
from ftcap_hil.ports.mailbox import Mailbox

log = logging.getLogger(__name__)
_LOG_LEVEL = {
    Severity.INFO: logging.INFO,
    Severity.WARNING: logging.WARNING,
    Severity.ERROR: logging.ERROR,
}


class ThrusterSink(Protocol):
    def send(self, u: FloatArray) -> bool: ...
    def send_zero(self) -> bool: ...
    def tick(self, now_ns: int | None = None) -> Any: ...


class StatusSink(Protocol):
    def publish(self, status: AllocatorStatus) -> None: ...
    def announce(self, text: str, severity: Severity) -> None: ...


@dataclass
class Ports:
    setpoints: list[Mailbox[WrenchSetpoint]]
    telemetry: list[Mailbox[Odometry]]
    thrusters: ThrusterSink
    status: list[StatusSink] = field(default_factory=list)
    esc_ages: Callable[[int], FloatArray] | None = None  # now_ns -> (m,) seconds
    esc_latest: Callable[[], Sequence[EscStatus | None]] | None = None  # per thruster


@dataclass(frozen=True)
class DaemonConfig:
    thrusters: ThrusterSet
    B: FloatArray
    plant: SurfaceVessel
    core: CoreConfig
    rate_hz: float = 1.0 / 0.2827
    estimation_period_s: float = 0.2827
    setpoint_timeout_s: float = 1.0
    telemetry_timeout_s: float = 1.0
    esc_timeout_s: float = 0.5
    status_period_s: float = 0.1
    wake_on_setpoint: bool = True
    # time command averages over telemetry intervals by VesselClock (else by receipt stamps)
    vessel_clock: bool = True
    dt_clamp: tuple[float, float] = (0.2, 5.0)  # dt for rate limits, in periods (PX4 clamps)


def _latest(boxes: Sequence[Mailbox[Any]]) -> tuple[Any, int]:
    """The freshest value over several mailboxes and its stamp (None, -1 if none yet)."""
    best, stamp = None, -1
    for box in boxes:
        slot = box.latest()
        if slot is not None and slot.stamp_ns > stamp:
            best, stamp = slot.value, slot.stamp_ns
    return best, stamp


class CommandHistory:
    """Commands with the time they went out, to average u over a telemetry interval."""

    def __init__(self, horizon_s: float) -> None:
        self._items: deque[tuple[int, FloatArray]] = deque()
        self._horizon_ns = int(horizon_s * 1e9)

    def add(self, stamp_ns: int, u: FloatArray) -> None:
        self._items.append((stamp_ns, u))
        while len(self._items) > 2 and self._items[1][0] < stamp_ns - self._horizon_ns:
            self._items.popleft()

    def mean(self, t0_ns: int, t1_ns: int) -> FloatArray | None:
        """Time-weighted mean of the piecewise-constant command over [t0, t1]."""
        if t1_ns <= t0_ns or not self._items or self._items[0][0] > t0_ns:
            return None
        acc, total = None, 0
        items = list(self._items)
        for i, (start, u) in enumerate(items):
            end = items[i + 1][0] if i + 1 < len(items) else t1_ns
            lo, hi = max(start, t0_ns), min(end, t1_ns)
            if hi > lo:
                acc = u * (hi - lo) if acc is None else acc + u * (hi - lo)
                total += hi - lo
        return None if acc is None else acc / total


class VesselClock:
    """Receipt stamps of telemetry corrected for their variable delay.

    A state measured at vessel time ``t`` (``Odometry.time_s``) reaches this process after a
    delay: the vessel's own computing, transport, this process's scheduling. Only the
    variable part matters to the command average (a constant one shifts every interval
    alike), and it was large in the qemu VM: tens of ms against a 283 ms estimation period.
    The least-delayed sample of the last ``window`` gives the clock offset, as in NTP's
    minimum filter or PX4's timesync: ``mapped = t + min(receipt - t)``.

    The mapping assumes the vessel's clock runs at this clock's rate. It is not used (the
    receipt stamp is) while it would move a stamp back by more than ``max_shift_s``: a
    vessel clock running slower (a sim below real time), a jump, or a restart. Vessel time
    going backwards restarts the filter.
    """

    def __init__(self, window: int = 50, max_shift_s: float = 0.25) -> None:
        self._offsets: deque[int] = deque(maxlen=window)
        self._last_t_ns: int | None = None
        self._max_shift_ns = int(max_shift_s * 1e9)

    def map(self, vessel_time_s: float, receipt_ns: int) -> int:
        """The receipt stamp corrected to the least-delayed offset (class docstring)."""
        if not math.isfinite(vessel_time_s):
            return receipt_ns
        t_ns = int(round(vessel_time_s * 1e9))
        if self._last_t_ns is not None and t_ns < self._last_t_ns:
            self._offsets.clear()
        self._last_t_ns = t_ns
        self._offsets.append(receipt_ns - t_ns)
        mapped = t_ns + min(self._offsets)
        return mapped if receipt_ns - mapped <= self._max_shift_ns else receipt_ns


class AllocatorDaemon:
    def __init__(self, config: DaemonConfig, ports: Ports) -> None:
        self.config = config
        self.ports = ports
        self.period_ns = int(1e9 / config.rate_hz)
        self.core = self._make_core(config.core)
        self.should_exit = False
        self.cycles = 0
        self.overruns = 0
        self.not_sent = 0  # commands the sink refused (bus errors)
        self._wake = threading.Event()
        if config.wake_on_setpoint:
            for box in ports.setpoints:
                box.notify = self._wake
        self._history = CommandHistory(horizon_s=10 * config.estimation_period_s + 5.0)
        # (receive stamp, odometry, the stamp that times the command average)
        self._est_sample: tuple[int, Odometry, int] | None = None
        self._clock = VesselClock()
        self._clock_fed = (-1, -1)  # (receive stamp, mapped stamp) of the last odometry
        self._last_cycle_ns: int | None = None
        self._last_status_ns = 0
        self._flags: dict[str, Any] = {}
        self._esc_bus_alive_ns: int | None = None  # when the first ESC was heard
        self._pending: list[Callable[[], None]] = []
        self.before_cycle: list[Callable[[], None]] = []  # hooks run in the loop thread
        self._pending_lock = threading.Lock()
        self._last: CycleResult | None = None
        self._saved_handlers: dict[int, Any] = {}
        self.last_status: AllocatorStatus | None = None
        self._malformed_seen = 0
        self._malformed_cycle = -(10**9)
        self._tau_d = np.zeros(config.B.shape[0])
        # setpoint mailbox stamp -> its command handed to the CAN sink (ns), per new setpoint
        self.reaction_ns: deque[int] = deque(maxlen=100_000)
        self.cycle_ns: deque[int] = deque(maxlen=200_000)  # duration of each cycle
        self._last_sp_stamp = -1

    def _make_core(self, core_cfg: CoreConfig) -> FtcapCore:
        dt = 1.0 / self.config.rate_hz
        return FtcapCore(self.config.B, self.config.thrusters, dt, core_cfg, self.config.plant)

    # --- called from other threads -----------------------------------------------------

    def call_in_loop(self, fn: Callable[[], None]) -> None:
        """Run fn in the loop thread before the next cycle (parameter changes)."""
        with self._pending_lock:
            self._pending.append(fn)
        self._wake.set()

    def request_exit(self, *_: object) -> None:
        self.should_exit = True
        self._wake.set()

    def set_mode(self, mode: Mode) -> None:
        """Rebuild the core in another mode, keeping what is on the thrusters."""
        u_prev = self.core.u_prev
        self.config = replace(self.config, core=replace(self.config.core, mode=mode))
        self.core = self._make_core(self.config.core)
        self.core.reset_command(u_prev)

    # --- the loop ----------------------------------------------------------------------

    def install_signal_handlers(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._saved_handlers[sig] = signal.signal(sig, self.request_exit)

    def restore_signal_handlers(self) -> None:
        for sig, handler in self._saved_handlers.items():
            signal.signal(sig, handler)
        self._saved_handlers.clear()

    def run(self, max_cycles: int | None = None) -> int:
        self.install_signal_handlers()
        # Bridge threads (pymavlink dispatch, zenoh callbacks, CAN notifier) share the GIL
        # with this loop; CPython's default 5 ms switch interval then shows up directly in
        # the setpoint -> frame latency (p99 3 ms measured). 0.2 ms bounds the hand-off.
        switch = sys.getswitchinterval()
        sys.setswitchinterval(2e-4)
        try:
            self.ports.thrusters.send_zero()
            next_deadline = time.monotonic_ns() + self.period_ns
            while not self.should_exit and (max_cycles is None or self.cycles < max_cycles):
                timeout = (next_deadline - time.monotonic_ns()) * 1e-9
                if timeout > 0 and self._wake.wait(timeout):
                    self._wake.clear()
                    if self.should_exit:
                        break
                now = time.monotonic_ns()
                self._run_pending()
                for hook in self.before_cycle:
                    hook()
                self.cycle(now)
                self.cycle_ns.append(time.monotonic_ns() - now)
                if now >= next_deadline:
                    next_deadline += self.period_ns
                    done = time.monotonic_ns()
                    if done > next_deadline:  # this cycle ran past the next deadline
                        missed = (done - next_deadline) // self.period_ns + 1
                        self.overruns += int(missed)
                        next_deadline += int(missed) * self.period_ns
        finally:
            sys.setswitchinterval(switch)
            self.shutdown()
        return 0

    def shutdown(self) -> None:
        """Zero thrust, whatever happened. Idempotent."""
        try:
            self.ports.thrusters.send_zero()
        finally:
            self.restore_signal_handlers()

    def _run_pending(self) -> None:
        with self._pending_lock:
            pending, self._pending = self._pending, []
        for fn in pending:
            fn()

    # --- one cycle ---------------------------------------------------------------------

    def cycle(self, now: int) -> CycleResult | None:
        cfg = self.config
        self.cycles += 1
        dt = None
        if self._last_cycle_ns is not None:
            period = self.period_ns * 1e-9
            lo, hi = cfg.dt_clamp
            dt = min(max((now - self._last_cycle_ns) * 1e-9, lo * period), hi * period)
        self._last_cycle_ns = now
        setpoint, sp_stamp = _latest(self.ports.setpoints)
        sp_age = math.inf if sp_stamp < 0 else (now - sp_stamp) * 1e-9
        odom, tel_stamp = _latest(self.ports.telemetry)
        tel_age = math.inf if tel_stamp < 0 else (now - tel_stamp) * 1e-9
        tel_stale = tel_age > cfg.telemetry_timeout_s
        esc_failed = self._esc_failed(now)
        self._transition(
            "telemetry_stale",
            tel_stale,
            "telemetry stale: estimation frozen",
            "telemetry recovered",
        )
        sp_stale = sp_age > cfg.setpoint_timeout_s
        self._transition(
            "setpoint_stale",
            sp_stale,
            "setpoint timeout: zero thrust",
            "setpoint received: allocating",
        )
        w, u_sample = (None, None) if tel_stale else self._estimation_sample(odom, tel_stamp)
        if sp_stale:
            result = None
            self._tau_d = np.zeros(self.core.k)
            self._send(np.zeros(self.core.m), now)
            self.core.reset_command()
        else:
            self._tau_d = setpoint.tau
            result = self.core.step(
                setpoint.tau, w, u_sample=u_sample, dt_s=dt, forced_dead=esc_failed
            )
            self._send(result.u, now)
            if sp_stamp != self._last_sp_stamp:
                self._last_sp_stamp = sp_stamp
                self.reaction_ns.append(time.monotonic_ns() - sp_stamp)
            self._report_transitions(result, esc_failed)
            self._last = result
        self.ports.thrusters.tick(now)
        if now - self._last_status_ns >= cfg.status_period_s * 1e9:
            self._last_status_ns = now
            self._publish(sp_age, tel_age, sp_stale, tel_stale, esc_failed)
        return result

    def _send(self, u: FloatArray, now: int) -> None:
        if not np.isfinite(u).all():  # cannot happen (the allocator clips), never on the bus
            log.error("non-finite command %s replaced by zero", u)
            u = np.zeros_like(u)
        if not self.ports.thrusters.send(u):
            self.not_sent += 1
        self._history.add(now, u)

    def _esc_failed(self, now: int) -> BoolArray | None:
        if self.ports.esc_ages is None:
            return None
        ages = self.ports.esc_ages(now)
        timeout = self.config.esc_timeout_s
        failed = ages > timeout  # never heard: age +inf, failed as well
        heard = np.isfinite(ages)
        if self._esc_bus_alive_ns is None and heard.any():
            self._esc_bus_alive_ns = now
        others_up = (
            self._esc_bus_alive_ns is not None and now - self._esc_bus_alive_ns > timeout * 1e9
        )
        for i, f in enumerate(failed):
            n = i + 1
            self._transition(
                f"esc-wait{n}",
                not heard[i],
                f"ESC {n} not heard yet: thruster held at 0",
                f"ESC {n} reporting",
                on_severity=Severity.INFO,
            )
            self._transition(
                f"esc{n}",
                bool(f) and (heard[i] or others_up),
                f"ESC {n} silent: thruster failed",
                f"ESC {n} reporting again",
            )
        return failed

    def _estimation_sample(self, odom: Odometry | None, stamp: int) -> tuple[Any, Any]:
        """w over the last estimation interval and the mean command over it, once per
        ``estimation_period_s`` of telemetry; (None, None) in between."""
        if odom is None:
            return None, None
        if stamp != self._clock_fed[0]:
            mapped = self._clock.map(odom.time_s, stamp) if self.config.vessel_clock else stamp
            self._clock_fed = (stamp, mapped)
        at = self._clock_fed[1]
        prev = self._est_sample
        if prev is None:
            self._est_sample = (stamp, odom, at)
            return None, None
        if stamp == prev[0]:
            return None, None
        # The interval is measured on the vessel's clock when telemetry carries it: receive
        # stamps jitter, and a threshold on them skipped about every other sample when the
        # telemetry period equals the estimation period (found by tests/e2e).
        dt = odom.time_s - prev[1].time_s
        if not (math.isfinite(dt) and dt > 0):
            dt = (stamp - prev[0]) * 1e-9
        if dt < 0.9 * self.config.estimation_period_s:
            return None, None
        self._est_sample = (stamp, odom, at)
        u_mean = self._history.mean(prev[2], at)
        if u_mean is None:
            return None, None
        x0 = np.concatenate([prev[1].eta, prev[1].nu])
        x1 = np.concatenate([odom.eta, odom.nu])
        return Observation(x0, x1, dt), u_mean

    def _transition(
        self, key: str, value: bool, on: str, off: str, on_severity: Severity = Severity.WARNING
    ) -> None:
        old = self._flags.get(key, False)
        if value != old:
            self._flags[key] = value
            self._announce(on if value else off, on_severity if value else Severity.INFO)

    def _report_transitions(self, r: CycleResult, esc_failed: BoolArray | None) -> None:
        for i, faulty in enumerate(r.faulty):
            d = r.estimate.delta_hat[i]
            self._transition(
                f"fault{i + 1}",
                bool(faulty),
                f"thruster {i + 1} fault detected: delta_hat {d:.2f}",
                f"thruster {i + 1} fault cleared: delta_hat {d:.2f}",
            )
        degraded = r.allocation.status is not AllocationStatus.OK
        self._transition(
            "degraded",
            degraded,
            f"allocation degraded: {r.allocation.status.value}",
            "allocation nominal",
        )

    def _announce(self, text: str, severity: Severity) -> None:
        log.log(_LOG_LEVEL[severity], "%s", text)
        for sink in self.ports.status:
            sink.announce(text, severity)

    def _esc_fields(self, now: int) -> dict[str, Any]:
        if self.ports.esc_latest is None or self.ports.esc_ages is None:
            return {}
        latest = self.ports.esc_latest()
        return {
            "esc_rpm": tuple(math.nan if e is None else float(e.rpm) for e in latest),
            "esc_current_a": tuple(math.nan if e is None else float(e.current_a) for e in latest),
            "esc_age_s": tuple(float(a) for a in self.ports.esc_ages(now)),
        }

    def status(
        self,
        sp_age: float,
        tel_age: float,
        sp_stale: bool,
        tel_stale: bool,
        esc_failed: BoolArray | None,
    ) -> AllocatorStatus:
        r, m = self._last, self.core.m
        est = r.estimate if r is not None else None

        def tup(a: Any, default: float | bool = 0.0) -> tuple[Any, ...]:
            return tuple(a.tolist()) if a is not None else (default,) * m

        return AllocatorStatus(
            mode=self.config.core.mode,
            cycle=self.cycles,
            overruns=self.overruns,
            degraded=bool(self._flags.get("degraded", False)),
            setpoint_stale=sp_stale,
            telemetry_stale=tel_stale,
            estimation_frozen=tel_stale and self.config.core.mode.estimates,
            delta_hat=tup(est.delta_hat if est else None, 1.0),
            f_hat=tup(est.f_hat if est else None),
            bf_hat=tuple(est.bf_hat.tolist()) if est else (0.0,) * self.core.k,
            u=tup(self.core.u_prev),
            tau_demand=tuple(self._tau_d.tolist()),
            unallocated=tuple(r.allocation.unallocated.tolist()) if r else (0.0,) * self.core.k,
            saturated=tup(r.allocation.saturated if r else None, False),
            faulty=tup(r.faulty if r else None, False),
            esc_failed=tup(esc_failed, False),
            probing=tup(r.probing if r else None, False),
            setpoint_age_s=sp_age,
            telemetry_age_s=tel_age,
            malformed=sum(b.malformed for b in self.ports.setpoints)
            + sum(b.malformed for b in self.ports.telemetry),
            **self._esc_fields(time.monotonic_ns()),
        )

    def _publish(self, *args: Any) -> None:
        st = self.status(*args)
        self.last_status = st
        for sink in self.ports.status:
            try:
                sink.publish(st)
            except (ValueError, OverflowError, TypeError, OSError, RuntimeError) as e:
                # A status that a bridge cannot encode must not end the loop.
                self._transition(
                    f"status:{type(sink).__name__}",
                    True,
                    f"status not published by {type(sink).__name__}: {e}",
                    "",
                )
                continue
            self._flags[f"status:{type(sink).__name__}"] = False
        if st.malformed > self._malformed_seen:
            self._malformed_seen = st.malformed
            if st.cycle - self._malformed_cycle >= self.config.rate_hz * 5:  # at most 1 per 5 s
                self._malformed_cycle = st.cycle
                self._announce(f"malformed input dropped: {st.malformed} so far", Severity.WARNING)
