"""The simulated vessel: true state, thrusters, true faults, command watchdog, ESC telemetry.

Pure: no I/O, no clock. The process shell (``ftcap_hil.runtime.vessel_process``) feeds it
commands with their receive stamps, fault injections, and steps it on its own deadlines.

Per step of length ``dt_s`` (sim time), with the faults held over the step (or each part
of it, below)::

    u     = clip(command, u_min, u_max)        if the command is fresh, else 0   (m,) N
    F     = delta * u + f                      produced force per thruster       (m,) N
    tau   = B F                                body-frame [X, Y, N]              (3,)
    x    <- SurfaceVessel.step_rk4(x, tau, dt_s)        x = [north, east, psi, u, v, r]
                                               psi then wrapped to (-pi, pi]

A command takes effect when it was received, as on a real thruster: if its stamp falls
inside the step (between the previous ``step`` call's ``now_s`` and this one's), the step is
split there and the command acting before keeps the first part, so the motion matches the
allocator's time average of its commands (docs/decisions.md). Only the latest command of a
step is known to the step. A scheduled fault change inside a step splits it too: the fault
acts from its scheduled time, not from the next step's start (up to one step late, which
decided whether an estimator sample straddled the onset), as in the offline simulator.

Watchdog: a command older than ``command_timeout_s`` (on the caller's clock, the one the
stamps come from: wall time even when the sim runs faster than real time) is dropped and the
thrusters get zero, like real ESCs that lose their input; faults still act, so a stuck
thruster keeps pushing its bias.

True faults, per thruster: the scenario ``FaultSchedule`` at the current sim time, overridden
by live injections (``FaultInjection``, latest wins per thruster and per quantity)::

    OK    -> (delta, f) = (1, 0)
    OFF   -> (0, 0)
    STUCK -> (0, value), NaN value = the force the thruster produced in the last step
    WEAK  -> (value, 0), NaN value = ``default_weak_delta``
    BIAS  -> (delta unchanged, value), NaN value = ``default_bias_n``

An ESC can be made silent (``silent`` windows, ``set_silent``): its thruster still works, its
telemetry stops; that is how the allocator's ESC-timeout path is exercised.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ftcap_hil.core.effectiveness.geometry import ThrusterSet
from ftcap_hil.core.faults import FaultSchedule, Truth
from ftcap_hil.core.messages import (
    BoolArray,
    EscStatus,
    FaultInjection,
    FaultKind,
    FloatArray,
    Odometry,
)
from ftcap_hil.core.models.plants import SurfaceVessel, wrap_angle
from sim.esc_model import DEFAULT_ESC, EscModel


@dataclass(frozen=True)
class SilentWindow:
    """ESC ``thruster`` (0-based) sends nothing for ``start_s <= t < end_s`` (sim time)."""

    thruster: int
    start_s: float = 0.0
    end_s: float = math.inf


@dataclass(frozen=True)
class VesselSimConfig:
    """The simulated vessel: plant, thrusters and B (3, m), initial state, the command
    watchdog (s, on the caller's clock), true faults (schedule and silent ESC windows), the
    ESC telemetry model, the defaults of value-less injections and the RK4 substeps."""

    plant: SurfaceVessel | None  # None: another truth steps the state (sim/live_truth.py)
    thrusters: ThrusterSet
    B: FloatArray  # (3, m)
    x0: FloatArray = field(default_factory=lambda: np.zeros(6))  # [north, east, psi, u, v, r]
    command_timeout_s: float = 0.5
    schedule: FaultSchedule | None = None
    silent: tuple[SilentWindow, ...] = ()
    esc: EscModel = DEFAULT_ESC
    default_weak_delta: float = 0.5
    default_bias_n: float = 0.08
    rk4_substeps: int = 8


@dataclass(frozen=True)
class SimSample:
    """The state at ``t_s`` and what acted over the step that ended there (SI, (m,) arrays)."""

    t_s: float
    x: FloatArray  # (6,) [north, east, psi, u, v, r]
    u: FloatArray  # command applied at the end of the step (after watchdog and clip), N
    command_fresh: bool
    command_age_s: float  # inf: no command ever
    produced: FloatArray  # F = delta u + f, N, mean over the step (a command may arrive in it)
    tau: FloatArray  # (3,) B F, mean over the step
    delta: FloatArray  # the true faults of the step's last part (a scheduled change splits it)
    f: FloatArray
    silent: BoolArray


class VesselSim:
    """See the module docstring. ``now_s`` / ``stamp_s`` share the caller's clock."""

    def __init__(self, config: VesselSimConfig) -> None:
        m = config.thrusters.m
        if config.B.shape != (3, m):
            raise ValueError(f"B: expected shape (3, {m}), got {config.B.shape}")
        if config.schedule is not None and config.schedule.m != m:
            raise ValueError(f"fault schedule for {config.schedule.m} thrusters, vessel has {m}")
        self.config = config
        self.m = m
        self._x = np.array(config.x0, dtype=np.float64)
        self._t_s = 0.0
        self._command = np.zeros(m)
        self._command_stamp_s = -math.inf  # when the command in force arrived (step split)
        self._heard_s = -math.inf  # when it (or a repeat of it) last arrived (watchdog)
        self._delta_override = np.full(m, np.nan)  # NaN: follow the schedule
        self._f_override = np.full(m, np.nan)
        self._silent_override: list[bool | None] = [None] * m
        self._produced = np.zeros(m)
        self._responding = np.ones(m, dtype=bool)
        self._acting = np.zeros(m)  # the command at the end of the last step
        self._last_now_s: float | None = None

    @property
    def t_s(self) -> float:
        """Sim time (s)."""
        return self._t_s

    @property
    def x(self) -> FloatArray:
        """A copy of the true state (6,) [north, east, psi, u, v, r]."""
        return self._x.copy()

    # --- inputs ---

    def set_command(self, u: FloatArray, stamp_s: float, first_s: float | None = None) -> None:
        """The latest thruster command (m,) N, received at ``stamp_s``; clipped to limits.

        An ESC command stream re-sends a command at its own rate: a repeat of the command in
        force only feeds the watchdog, and a new value whose first copy came at ``first_s``
        (the receiver may only hand over its latest copy) took effect then, though not
        before the previous command was last heard."""
        u = np.asarray(u, dtype=np.float64)
        if u.shape != (self.m,) or not np.all(np.isfinite(u)):
            raise ValueError(f"command: expected {self.m} finite forces, got {u.tolist()}")
        ths = self.config.thrusters
        u = np.clip(u, ths.u_min, ths.u_max)
        repeat = stamp_s - self._heard_s <= self.config.command_timeout_s
        if not (repeat and np.array_equal(u, self._command)):
            self._command = u
            effect = stamp_s if first_s is None else min(first_s, stamp_s)
            self._command_stamp_s = max(effect, self._heard_s)
        self._heard_s = stamp_s

    def inject(self, fault: FaultInjection) -> None:
        """Apply a live injection (module docstring). ValueError for a bad index or value."""
        i, value = fault.index, fault.value
        if not 0 <= i < self.m:
            raise ValueError(f"fault injection: thruster index {i} not in 0..{self.m - 1}")
        if math.isinf(value):
            raise ValueError(f"fault injection: infinite value for thruster {i}")
        given = not math.isnan(value)
        if fault.kind is FaultKind.OK:
            self._delta_override[i], self._f_override[i] = 1.0, 0.0
        elif fault.kind is FaultKind.OFF:
            self._delta_override[i], self._f_override[i] = 0.0, 0.0
        elif fault.kind is FaultKind.STUCK:
            self._delta_override[i] = 0.0
            self._f_override[i] = value if given else self._produced[i]
        elif fault.kind is FaultKind.WEAK:
            delta = value if given else self.config.default_weak_delta
            if not 0.0 <= delta <= 1.0:
                raise ValueError(f"fault injection: WEAK delta {delta} not in [0, 1]")
            self._delta_override[i], self._f_override[i] = delta, 0.0
        else:  # BIAS
            self._f_override[i] = value if given else self.config.default_bias_n

    def set_silent(self, index: int, silent: bool | None) -> None:
        """Force ESC ``index`` silent (True) or reporting (False); None: follow the windows."""
        self._silent_override[index] = silent

    # --- truth ---

    def faults(self) -> Truth:
        """True (delta, f) acting now: schedule at ``t_s`` overridden by injections."""
        return self._truth_at(self._t_s)

    def _truth_at(self, t_s: float) -> Truth:
        """True (delta, f) at sim time ``t_s``: the schedule overridden by injections."""
        if self.config.schedule is not None:
            base = self.config.schedule.at(t_s)
            delta, f = base.delta, base.f
        else:
            delta, f = np.ones(self.m), np.zeros(self.m)
        return Truth(
            np.where(np.isnan(self._delta_override), delta, self._delta_override),
            np.where(np.isnan(self._f_override), f, self._f_override),
        )

    def silent(self) -> BoolArray:
        """(m,) ESCs silent now: the windows at ``t_s``, overridden by ``set_silent``."""
        out = np.zeros(self.m, dtype=bool)
        for w in self.config.silent:
            if w.start_s <= self._t_s < w.end_s:
                out[w.thruster] = True
        for i, forced in enumerate(self._silent_override):
            if forced is not None:
                out[i] = forced
        return out

    # --- dynamics ---

    def command_age_s(self, now_s: float) -> float:
        """Seconds from the latest command's stamp to ``now_s`` (inf if none arrived)."""
        return now_s - self._heard_s

    def step(self, dt_s: float, now_s: float) -> SimSample:
        """Integrate ``dt_s`` of sim time; the watchdog compares stamps with ``now_s``."""
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f"dt_s: expected a finite positive step, got {dt_s}")
        age = self.command_age_s(now_s)
        fresh = age <= self.config.command_timeout_s
        u = self._command.copy() if fresh else np.zeros(self.m)
        silent = self.silent()
        # Fraction of the step that ran before the latest command arrived (module docstring).
        before = 0.0
        last = self._last_now_s
        if fresh and last is not None and last < self._command_stamp_s < now_s:
            before = (self._command_stamp_s - last) / (now_s - last)
        prev = self._acting
        produced_sum = np.zeros(self.m)
        t0 = self._t_s
        for at_s, frac, new_command in self._parts(dt_s, before):
            truth = self._truth_at(at_s)
            produced = self._integrate(truth, u if new_command else prev, frac * dt_s)
            produced_sum += frac * produced
        self._x[2] = float(wrap_angle(self._x[2]))  # psi in (-pi, pi], as telemetry reports it
        self._t_s = t0 + dt_s
        self._produced = produced
        self._responding = truth.delta > 0.0
        self._acting = u
        self._last_now_s = now_s
        shown = self._recorded(truth)
        return SimSample(
            self._t_s, self._x.copy(), u, fresh, age, produced_sum, self.config.B @ produced_sum,
            shown.delta, shown.f, silent,
        )  # fmt: skip

    def _integrate(self, truth: Truth, u: FloatArray, h_s: float) -> FloatArray:
        """Advance the state by ``h_s`` under ``truth`` with the command ``u`` (m,) N held;
        the mean force each thruster produced over it (m,) N. The paper's plant:
        F = delta u + f, RK4 (a subclass steps another truth)."""
        plant = self.config.plant
        if plant is None:
            raise ValueError("VesselSim: the paper's plant is needed (config.plant is None)")
        produced: FloatArray = truth.delta * u + truth.f
        self._x = plant.step_rk4(self._x, self.config.B @ produced, h_s, self.config.rk4_substeps)
        return produced

    def _recorded(self, truth: Truth) -> Truth:
        """The faults a sample reports for the step's last part (as seen from the command)."""
        return truth

    def _parts(self, dt_s: float, before: float) -> list[tuple[float, float, bool]]:
        """The step [t, t + dt_s] cut where the latest command arrived (``before``, a fraction
        of the step) and where the fault schedule changes: per part, the sim time its faults
        are taken at (a schedule change: exactly its time), its fraction of the step, and
        whether the latest command acts in it."""
        t = self._t_s
        edges = [(0.0, t)]
        if before > 0.0:
            edges.append((before, t + before * dt_s))
        if self.config.schedule is not None:
            changes = self.config.schedule.change_times()
            edges += [((c - t) / dt_s, c) for c in changes if t < c < t + dt_s]
        edges.sort()
        edges.append((1.0, t + dt_s))
        return [
            (at_s, b - a, a >= before)
            for (a, at_s), (b, _) in zip(edges[:-1], edges[1:], strict=True)
            if b > a
        ]

    def esc_statuses(self) -> list[EscStatus]:
        """Telemetry of the last step's produced forces, for the ESCs that are not silent."""
        return self.config.esc.statuses(self._produced, self._responding, ~self.silent())

    # --- what the shell publishes after a step ---

    def odometry(self, sample: SimSample, due: bool) -> list[Odometry]:
        """The odometry to publish after the step that gave ``sample``: the exact state when
        the shell's telemetry stream is ``due`` (a truth with a sensor: what it delivered)."""
        return [Odometry.checked(sample.x[:3], sample.x[3:], sample.t_s)] if due else []

    def reporting(self) -> BoolArray:
        """(m,) ESCs whose telemetry is on now (not silent)."""
        return ~self.silent()

    def esc_reports(self, due: bool) -> list[EscStatus] | None:
        """The ESC telemetry to send now (None: nothing this step): the ESC model's statuses
        of the produced forces when the shell's ESC stream is ``due``."""
        return self.esc_statuses() if due else None


# --- helpers of the process shell (pure) ---


class Decimator:
    """True on the steps where an ``out_hz`` stream is due in a ``rate_hz`` loop (step 0 too)."""

    def __init__(self, rate_hz: float, out_hz: float) -> None:
        self._ratio = min(out_hz / rate_hz, 1.0)
        self._step = 0

    def due(self) -> bool:
        """Advance one step; True if the stream is due on it."""
        k = self._step
        self._step += 1
        return k == 0 or math.floor(k * self._ratio) > math.floor((k - 1) * self._ratio)


def record_header(names: list[str]) -> list[str]:
    """Columns of the ``--record`` CSV; per-thruster columns use the thruster names."""
    per = [(f"u_{n}_N", f"F_{n}_N", f"delta_{n}", f"f_{n}_N", f"silent_{n}") for n in names]
    grouped = [col for k in range(5) for col in (p[k] for p in per)]
    head = ["time_s", "monotonic_s", "north_m", "east_m", "psi_rad", "u_mps", "v_mps", "r_radps"]
    return [*head, "command_fresh", "command_age_s", *grouped, "tau_X_N", "tau_Y_N", "tau_N_Nm"]


def record_row(s: SimSample, monotonic_s: float) -> list[Any]:
    """One ``--record`` CSV row of ``s`` (columns of :func:`record_header`)."""
    row: list[Any] = [f"{s.t_s:.6f}", f"{monotonic_s:.6f}", *s.x.tolist()]
    row += [int(s.command_fresh), s.command_age_s]
    for arr in (s.u, s.produced, s.delta, s.f):
        row += arr.tolist()
    row += s.silent.astype(int).tolist()
    row += s.tau.tolist()
    return row
