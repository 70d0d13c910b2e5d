"""The estimator's samples: the plant's state at both ends of an interval and the mean command
over the same interval.

Once per ``estimation_period_s`` of telemetry (the newest sample over the telemetry ports,
:func:`newest_odometry`), :class:`EstimationSampler` pairs two odometry
samples ``x0 = [eta, nu]`` and ``x1`` (NED pose, body velocities) ``dt`` apart, as a core
:class:`~ftcap_hil.core.estimation.Observation`, with the time-weighted mean of the commands
the thrusters had over that interval (from a :class:`CommandHistory` of what was sent, with
its stamps). The command interval is found on this process's clock: the receipt stamps,
corrected by :class:`VesselClock` for the telemetry's variable delay.
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


class EstimationSampler:
    """Pairs telemetry with the commands sent (module docstring).

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
        self._clock_fed = (-1, -1)  # (receipt stamp, mapped stamp) of the last odometry
        self._last: _Point | None = None

    def restart(self) -> None:
        """Start a new interval at the next sample: what lies before may not be trusted."""
        self._last = None

    def command_sent(self, stamp_ns: int, u: FloatArray) -> None:
        """Command ``u`` (m,) in N went to the thrusters at ``stamp_ns``."""
        self.history.add(stamp_ns, u)

    def sample(self, odom: Odometry | None, receipt_ns: int) -> EstimationSample | None:
        """A sample when the latest telemetry (``odom`` received at ``receipt_ns``) closes an
        interval of at least 0.9 estimation periods since the last one; None in between."""
        if odom is None:
            return None
        if receipt_ns != self._clock_fed[0]:  # a new sample: judged once, then timed
            if not self.gate.check(odom, receipt_ns):
                # dropped before the estimator: the interval goes on to the next good sample
                self._clock_fed = (receipt_ns, receipt_ns)
                return None
            mapped = (
                self._clock.map(odom.time_s, receipt_ns) if self.use_vessel_clock else receipt_ns
            )
            self._clock_fed = (receipt_ns, mapped)
        elif self.gate.reason is not None:
            return None  # the same implausible sample, seen again by a later cycle
        point = _Point(receipt_ns, odom, self._clock_fed[1])
        prev = self._last
        if prev is None:
            self._last = point
            return None
        if receipt_ns == prev.receipt_ns:
            return None
        # The interval is measured on the vessel's clock when telemetry carries it: receipt
        # stamps jitter, and a threshold on them skips samples whenever the telemetry period
        # equals the estimation period.
        dt = odom.time_s - prev.odom.time_s
        if math.isfinite(dt) and dt <= 0:  # vessel time went back (a restart): a new interval
            self._last = point
            return None
        if not math.isfinite(dt):  # no vessel time: the receipt stamps
            dt = (receipt_ns - prev.receipt_ns) * 1e-9
        if dt < 0.9 * self.period_s:
            return None
        self._last = point
        u_mean = self.history.mean(prev.at_ns, point.at_ns)
        if u_mean is None:
            return None
        x0 = np.concatenate([prev.odom.eta, prev.odom.nu])
        x1 = np.concatenate([odom.eta, odom.nu])
        return EstimationSample(Observation(x0, x1, dt), u_mean)
