"""The estimator's samples: the plant's state at both ends of an interval and the mean command
over the same interval.

The intervals lie on **the vessel's grid**: their ends are the first telemetry samples at or
after each multiple of ``estimation_period_s`` of vessel time (``Odometry.time_s``), as the
offline loop samples at ``k T_s``. :class:`EstimationSampler` is handed every sample the
chosen port received (:meth:`EstimationSampler.observe`), not only the newest at a cycle,
so which states pair up does not depend on the phase of the allocator's deadlines against
the vessel's steps, nor on a late cycle; each cycle takes the interval closed since the
last (:meth:`EstimationSampler.take`). A telemetry stream without vessel time falls back to
receipt stamps: an interval of at least 0.9 periods ending at the newest sample.

Each interval is paired, as a core :class:`~ftcap_hil.core.estimation.Observation`, with
the time-weighted mean of the commands the thrusters had over it (from a
:class:`CommandHistory` of what was sent, with its stamps), found on this process's clock:
the receipt stamps, corrected by :class:`VesselClock` for the telemetry's variable delay.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ftcap_hil.config.daemon import OdometryLimits
from ftcap_hil.core.estimation.stages import Observation
from ftcap_hil.core.messages import FloatArray, Odometry
from ftcap_hil.ports.mailbox import Stamped


def newest_odometry(
    slots: Sequence[Stamped[Odometry] | None], window_ns: int
) -> Stamped[Odometry] | None:
    """The newest measurement among the telemetry ports' latest samples (None: none yet).

    The same odometry often comes over two transports (MAVLink and Zenoh), one copy a
    millisecond or more after the other, so by receipt stamps alone the late copy of an older
    sample can win over a newer one. Among the samples received within ``window_ns`` of the
    latest receipt (a port gone silent drops out), the latest vessel time
    (``Odometry.time_s``) wins, its first copy on a tie (the least delayed); if one of them
    carries no vessel time, the latest receipt.
    """
    got = [s for s in slots if s is not None]
    if not got:
        return None
    last = max(s.stamp_ns for s in got)
    recent = [s for s in got if s.stamp_ns >= last - window_ns]
    if not all(math.isfinite(s.value.time_s) for s in recent):
        return max(recent, key=lambda s: s.stamp_ns)
    return max(recent, key=lambda s: (s.value.time_s, -s.stamp_ns))


class CommandHistory:
    """Commands with the time they went out, to average u over a telemetry interval."""

    def __init__(self, horizon_s: float) -> None:
        self._items: deque[tuple[int, FloatArray]] = deque()
        self._horizon_ns = int(horizon_s * 1e9)

    def add(self, stamp_ns: int, u: FloatArray) -> None:
        """Command ``u`` (m,) in N went out at ``stamp_ns``; older ones beyond the horizon go."""
        self._items.append((stamp_ns, u))
        while len(self._items) > 2 and self._items[1][0] < stamp_ns - self._horizon_ns:
            self._items.popleft()

    def mean(self, t0_ns: int, t1_ns: int) -> FloatArray | None:
        """Time-weighted mean (m,) of the piecewise-constant command over [t0, t1]; None if
        the interval is empty or starts before the oldest command kept."""
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
    alike). The least-delayed sample of the last ``window`` gives the clock offset, as in
    NTP's minimum filter or PX4's timesync: ``mapped = t + min(receipt - t)``.

    The mapping assumes the vessel's clock runs at this clock's rate. It is not used (the
    receipt stamp is) while it would move a stamp back by more than ``max_shift_s``: a
    vessel clock running slower (a sim below real time), a jump, or a restart. Vessel time
    going backwards restarts the filter.
    """

    def __init__(self, window: int = 50, max_shift_s: float = 0.25, rate: float = 1.0) -> None:
        self._rate = rate  # vessel seconds per second of this clock (a faster sim: > 1)
        self._offsets: deque[int] = deque(maxlen=window)
        self._last_t_ns: int | None = None
        self._max_shift_ns = int(max_shift_s * 1e9)

    def map(self, vessel_time_s: float, receipt_ns: int) -> int:
        """The receipt stamp corrected to the least-delayed offset (class docstring)."""
        if not math.isfinite(vessel_time_s):
            return receipt_ns
        t_ns = int(round(vessel_time_s / self._rate * 1e9))
        if self._last_t_ns is not None and t_ns < self._last_t_ns:
            self._offsets.clear()
        self._last_t_ns = t_ns
        self._offsets.append(receipt_ns - t_ns)
        mapped = t_ns + min(self._offsets)
        return mapped if receipt_ns - mapped <= self._max_shift_ns else receipt_ns


def track_jump(
    limits: OdometryLimits, prev: tuple[Odometry, int], odom: Odometry, receipt_ns: int
) -> str | None:
    """Why ``odom`` (received at ``receipt_ns``) cannot follow ``prev`` (a sample and its
    receipt stamp) on one vessel's track, or None if it can: a position that moved more
    than ``max_speed dt + position_margin`` or a velocity that changed more than
    ``max_accel dt + velocity_margin``, ``dt`` on the vessel's clock when it runs forward
    between them, else the receipt stamps (either order)."""
    p_odom, p_receipt = prev
    dt = odom.time_s - p_odom.time_s
    if not math.isfinite(dt) or dt < 0:
        dt = abs(receipt_ns - p_receipt) * 1e-9
    moved = math.hypot(odom.eta[0] - p_odom.eta[0], odom.eta[1] - p_odom.eta[1])
    if moved > limits.max_speed_m_s * dt + limits.position_margin_m:
        return f"position jumped {moved:.3g} m in {dt:.3g} s"
    dv = math.hypot(odom.nu[0] - p_odom.nu[0], odom.nu[1] - p_odom.nu[1])
    if dv > limits.max_accel_m_s2 * dt + limits.velocity_margin_m_s:
        return f"velocity jumped {dv:.3g} m/s in {dt:.3g} s"
    return None


class PlausibilityGate:
    """Drops odometry the vessel cannot have produced, before it reaches the estimator.

    Implausible: a non-finite value; a speed or yaw rate beyond the limits; a sample that
    cannot follow the last kept one (:func:`track_jump`). A forged sample among the
    vessel's own costs only itself. A genuine jump (a GNSS re-fix) starts a new track that
    is kept once it has followed on from itself for ``refix_s`` with no sample of the old
    track in between; until then its samples are dropped (estimation paused, announced).
    So the gate cannot lock itself out, and a forged track that takes turns with the
    vessel's never becomes the estimator's.
    """

    def __init__(self, limits: OdometryLimits | None = None, refix_s: float = 2.0) -> None:
        self.limits = limits or OdometryLimits()
        self.refix_ns = int(refix_s * 1e9)
        self.rejected = 0
        self.reason: str | None = None  # why the last sample was dropped; None: it was kept
        self._kept: tuple[Odometry, int] | None = None
        self._pending: tuple[Odometry, int] | None = None  # the new track's latest sample
        self._pending_since = 0  # receipt stamp of the new track's first sample

    def check(self, odom: Odometry, receipt_ns: int) -> bool:
        """True when ``odom`` is plausible (counted and ``reason`` set otherwise)."""
        self.reason = self._why(odom, receipt_ns)
        if self.reason is None:
            self._kept, self._pending = (odom, receipt_ns), None
        else:
            self.rejected += 1
        return self.reason is None

    def _why(self, odom: Odometry, receipt_ns: int) -> str | None:
        lim = self.limits
        eta, nu = np.asarray(odom.eta, dtype=np.float64), np.asarray(odom.nu, dtype=np.float64)
        if not (np.all(np.isfinite(eta)) and np.all(np.isfinite(nu))):
            return "non-finite pose or velocity"
        speed = math.hypot(nu[0], nu[1])
        if speed > lim.max_speed_m_s:
            return f"speed {speed:.3g} m/s > {lim.max_speed_m_s:g}"
        if abs(nu[2]) > lim.max_yaw_rate_rad_s:
            return f"yaw rate {nu[2]:.3g} rad/s beyond {lim.max_yaw_rate_rad_s:g}"
        if self._kept is None:
            return None
        jump = track_jump(lim, self._kept, odom, receipt_ns)
        if jump is None:
            return None
        pending, self._pending = self._pending, (odom, receipt_ns)
        if pending is None or track_jump(lim, pending, odom, receipt_ns) is not None:
            self._pending_since = receipt_ns  # a new track starts here
        elif receipt_ns - self._pending_since >= self.refix_ns:
            return None  # the new track held on its own: the vessel's track moved
        held = (receipt_ns - self._pending_since) * 1e-9
        return f"{jump}; a new track for {held:.1f} s"


class EstimationSample(NamedTuple):
    """The states at both ends of an interval (``observation``, vessel-clock ``dt_s``) and the
    mean command ``u_mean`` (m,) in N over it."""

    observation: Observation
    u_mean: FloatArray


class _Point(NamedTuple):
    receipt_ns: int
    odom: Odometry
    at_ns: int  # the stamp that times the command average


# A sample up to this much vessel time older than the last one seen is a late copy from
# another port (two ports carry the same samples, one may lag a sample or two); further
# back, the vessel restarted.
RESTART_BACK_S = 1.0
# The grid's ends are at least this share of a period apart: a sample that reaches the next
# multiple right after a gap (a dropped or late sample) closes no interval of its own.
MIN_INTERVAL = 0.5
# Intervals closed and not taken yet: each cycle takes the oldest, so two closing between two
# cycles (the telemetry's own spacing) are both judged, one a cycle late; beyond this many
# (cycles slower than the grid) the oldest two are merged, so the estimate never lags more.
MAX_PENDING = 2
# A sample this close before a multiple of the period is at it: vessel times travel as whole
# microseconds (MAVLink's time_usec, truncated) or float32, so k T_s may arrive as k T_s - 1 us.
GRID_SLACK_S = 1e-3


class EstimationSampler:
    """Pairs telemetry with the commands sent on the vessel's grid (module docstring).

    ``use_vessel_clock``: time the command average by :class:`VesselClock` (else by the
    receipt stamps); ``time_scale``: the vessel's seconds per second of this clock.
    """

    def __init__(
        self,
        period_s: float,
        use_vessel_clock: bool,
        limits: OdometryLimits | None = None,
        time_scale: float = 1.0,
    ) -> None:
        self.period_s = period_s
        self.gate = PlausibilityGate(limits)
        self.use_vessel_clock = use_vessel_clock
        self.history = CommandHistory(horizon_s=10 * period_s + 5.0)
        self._clock = VesselClock(rate=time_scale)
        self._seen: tuple[int, float] | None = None  # (receipt, vessel time) last judged
        self._last: _Point | None = None  # the grid's latest end
        self._cell = 0  # its multiple of the period
        self._closed: deque[tuple[_Point, _Point]] = deque()  # intervals not taken yet

    def restart(self) -> None:
        """Start a new interval at the next sample: what lies before may not be trusted."""
        self._last = None
        self._closed.clear()

    def command_sent(self, stamp_ns: int, u: FloatArray) -> None:
        """Command ``u`` (m,) in N went to the thrusters at ``stamp_ns``."""
        self.history.add(stamp_ns, u)

    def sample(self, odom: Odometry | None, receipt_ns: int) -> EstimationSample | None:
        """:meth:`observe` the latest telemetry (``odom`` received at ``receipt_ns``), then
        :meth:`take` (a caller that sees only the newest sample per cycle)."""
        if odom is not None:
            self.observe(odom, receipt_ns)
        return self.take()

    def _new(self, odom: Odometry, receipt_ns: int) -> bool:
        """Whether ``odom`` was not judged yet: a later vessel time (or, without one, a
        later receipt); a vessel time far back (``RESTART_BACK_S``) is a restart."""
        seen = self._seen
        if seen is None:
            return True
        t, (seen_rx, seen_t) = odom.time_s, seen
        if not (math.isfinite(t) and math.isfinite(seen_t)):
            return receipt_ns > seen_rx
        return t > seen_t or t < seen_t - RESTART_BACK_S

    def observe(self, odom: Odometry, receipt_ns: int) -> None:
        """One telemetry sample, received at ``receipt_ns``: judged once (the plausibility
        gate), timed, and placed on the grid; a copy or a sample seen already changes nothing
        (``gate.reason`` keeps the last verdict)."""
        if not self._new(odom, receipt_ns):
            return
        self._seen = (receipt_ns, odom.time_s)
        if not self.gate.check(odom, receipt_ns):
            return  # dropped before the estimator: the interval goes on to the next good one
        at = self._clock.map(odom.time_s, receipt_ns) if self.use_vessel_clock else receipt_ns
        point, prev = _Point(receipt_ns, odom, at), self._last
        t = odom.time_s
        if not math.isfinite(t):
            if prev is None or (receipt_ns - prev.receipt_ns) * 1e-9 >= 0.9 * self.period_s:
                self._close(prev, point, 0)
            return
        cell = math.floor((t + GRID_SLACK_S) / self.period_s)
        if prev is None or not math.isfinite(prev.odom.time_s) or t <= prev.odom.time_s:
            self._last, self._cell = point, cell  # a new start
            self._closed.clear()
        elif cell > self._cell and t - prev.odom.time_s >= MIN_INTERVAL * self.period_s:
            self._close(prev, point, cell)

    def _close(self, prev: _Point | None, point: _Point, cell: int) -> None:
        """``point`` ends the grid's interval from ``prev``, queued for :meth:`take`; past
        ``MAX_PENDING`` the two oldest become one (no stretch of the motion goes unjudged)."""
        if prev is not None:
            self._closed.append((prev, point))
            if len(self._closed) > MAX_PENDING:
                first, second = self._closed.popleft(), self._closed.popleft()
                self._closed.appendleft((first[0], second[1]))
        self._last, self._cell = point, cell

    def take(self) -> EstimationSample | None:
        """The oldest interval closed and not taken yet, with its mean command (None: none,
        or no command known over all of it)."""
        if not self._closed:
            return None
        prev, point = self._closed.popleft()
        u_mean = self.history.mean(prev.at_ns, point.at_ns)
        if u_mean is None:
            return None
        dt = point.odom.time_s - prev.odom.time_s
        if not math.isfinite(dt):
            dt = (point.receipt_ns - prev.receipt_ns) * 1e-9
        x0 = np.concatenate([prev.odom.eta, prev.odom.nu])
        x1 = np.concatenate([point.odom.eta, point.odom.nu])
        return EstimationSample(Observation(x0, x1, dt), u_mean)
