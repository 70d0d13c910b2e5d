"""Constrained allocation: step 3 of F-TCAP (eq. 13) with the slack eliminated.

    u = argmin  || B Delta_hat u + b_hat - tau_d ||^2_Qs  +  || u - u_pref ||^2_Ru
        s.t.    u in Omega(u_prev)    (amplitude box  intersected with  rate box, eq. 2)

A demand more than 10 times the achievable wrench is shrunk along its own direction
first (the result is the same saturated allocation, and the solver never sees 1e300 N).
Qs = slack_weight / S^2 and Ru = effort_weight / u_range^2 keep the weights dimensionless;
slack_weight >> effort_weight makes the wrench equation of eq. (13) nearly hard, so a
feasible demand is met to ~effort_weight/slack_weight relative accuracy and an infeasible
one is met in the Qs-weighted least-squares sense. u_pref is zero except for the estimator's
excitation (``excitation.py``). Thrusters with delta_hat below ``dead_threshold`` are taken
out: their box shrinks to {0} (reached at the allowed rate) unless they are being probed.

If the QP backend fails, the clipped pseudo-inverse is used and the allocation is flagged
``FALLBACK``. The command is always finite and inside Omega(u_prev).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.allocation.qp import make_solver
from ftcap_hil.core.effectiveness.geometry import ThrusterSet, command_bounds
from ftcap_hil.core.frozen import fast_init
from ftcap_hil.core.messages import BoolArray, FloatArray

_MAX_DEMAND = 10.0  # |tau_d - b_hat| / S beyond this is scaled down before the QP: the
# allocation is the same (saturated towards that direction) and the QP stays well scaled.
_DELTA_STILL = 1e-9  # delta_hat moves below this (max abs): the QP's H is reused as is


class AllocationStatus(enum.Enum):
    """How one allocation was obtained."""

    OK = "ok"
    FALLBACK = "fallback"  # solver failed; clipped pseudo-inverse used
    INVALID_DEMAND = "invalid-demand"  # non-finite demand; zero demand allocated


@dataclass(frozen=True)
class AllocatorConfig:
    """Weights of eq. (13) and the dead threshold; ValueError on construction if invalid.

    ``slack_weight`` (> 0) and ``effort_weight`` (> 0) are dimensionless (Qs and Ru are
    scaled by S and the thruster ranges, module docstring). A thruster whose delta_hat is
    below ``dead_threshold`` (in [0, 1)) is taken out. ``backend``: the QP backend name
    (:func:`ftcap_hil.core.qp.make_solver`).
    """

    slack_weight: float = 1e6
    effort_weight: float = 1.0
    dead_threshold: float = 0.1
    backend: str = "daqp"

    def __post_init__(self) -> None:
        if not self.slack_weight > 0 or not self.effort_weight > 0:
            raise ValueError("allocator: slack_weight and effort_weight must be > 0")
        if not 0.0 <= self.dead_threshold < 1.0:
            raise ValueError(f"allocator.dead_threshold: need [0, 1), got {self.dead_threshold}")


@fast_init  # built every cycle (core/frozen.py)
@dataclass(frozen=True)
class Allocation:
    """The result of one :meth:`Allocator.allocate`; wrenches (k,) are [X (N), Y (N), N (N*m)]
    in the body frame, per-thruster arrays (m,) in vessel-file order."""

    u: FloatArray  # (m,) commands (N), inside Omega(u_prev)
    tau_planned: FloatArray  # (k,) B Delta_hat u + b_hat: what the allocator expects to get
    unallocated: FloatArray  # (k,) tau_d - tau_planned
    saturated: BoolArray  # (m,): at an amplitude or rate bound
    dead: BoolArray  # (m,): taken out of the allocation
    status: AllocationStatus
    iterations: int = 0


class Allocator:
    """Step 3 of F-TCAP (module docstring) on one persistent, warm-started QP workspace.

    ``B`` (k, m): effectiveness matrix (N, N, N*m per N of thrust). ``thrusters``: amplitude
    limits u_min/u_max (N) and rate limits. ``dt_s``: the configured allocation period (s),
    which sizes the rate box. ``scale`` (k,): S, the largest achievable |tau| per axis
    (:func:`ftcap_hil.core.estimator.wrench_scale`). Called from one thread only.
    """

    def __init__(
        self,
        B: FloatArray,
        thrusters: ThrusterSet,
        dt_s: float,
        scale: FloatArray,
        config: AllocatorConfig | None = None,
    ) -> None:
        self.config = config or AllocatorConfig()
        self._B = np.array(B, dtype=np.float64)
        self._u_min = thrusters.u_min
        self._u_max = thrusters.u_max
        self._thrusters = thrusters
        self._step = thrusters.max_step(dt_s)  # for the configured period
        self._step_at: tuple[float, FloatArray] = (dt_s, self._step)  # last other dt
        u_range = np.maximum(np.abs(self._u_min), np.abs(self._u_max))
        self._scale = np.asarray(scale, dtype=np.float64)
        self._u_range = u_range
        # The QP is solved in commands scaled to each thruster's range (u = D x): in newtons
        # a full-scale vessel's H spans 1e-11 (effort) to 1e-6 (slack), below the solvers'
        # zero tolerances, and both backends returned 40 % of the optimum (or no answer).
        self._D = np.maximum(u_range, 1e-300)
        self._solver = make_solver(self.config.backend, self._B.shape[1])
        self._small_demand = _MAX_DEMAND * float(self._scale.min())  # below: never shrunk
        self._h_key: FloatArray | None = None  # delta_hat that _beff and _H were built for
        self._h_list: list[float] = []  # the same as a list (the common case: unchanged)
        self._beff = self._B.copy()
        self._H = np.zeros((self._B.shape[1],) * 2)
        self.retune(self.config)
        self._tol = 1e-9 * (u_range + 1.0)  # "at a bound" for the saturation flags

    def retune(self, config: AllocatorConfig) -> None:
        """New weights / dead threshold, same solver workspace (the backend is fixed)."""
        if config.backend != self.config.backend:
            raise ValueError("allocator.backend cannot change on a running allocator")
        self.config = config
        self._qs = config.slack_weight / self._scale**2
        self._ru = config.effort_weight / self._u_range**2
        self._qs_col = self._qs[:, None]  # H's parts that delta_hat does not change
        self._ru_d2 = self._ru * self._D**2
        self._h_key = None

    @property
    def backend(self) -> str:
        """Name of the QP backend in use."""
        return self._solver.name

    def _effective(self, delta_hat: FloatArray) -> tuple[FloatArray, FloatArray]:
        """B Delta_hat and the QP's H for it in the scaled commands x = u / range, rebuilt
        only when delta_hat moved by more than _DELTA_STILL since the last build: the same H
        array handed back lets the proxsuite workspace skip its set-up (docs/decisions.md)."""
        key = self._h_key
        if key is None or (
            delta_hat.tolist() != self._h_list and np.abs(delta_hat - key).max() > _DELTA_STILL
        ):
            beff = self._B * delta_hat
            scaled = beff * self._D
            H = scaled.T @ (self._qs_col * scaled)
            H.flat[:: H.shape[0] + 1] += self._ru_d2
            self._h_key, self._beff, self._H = delta_hat.copy(), beff, H
            self._h_list = self._h_key.tolist()
        return self._beff, self._H

    def _shrunk(self, target: FloatArray) -> FloatArray:
        """``target`` (k,), or the same direction at _MAX_DEMAND times S when it is larger
        (a NaN anywhere: as it is, as numpy's max would leave it)."""
        values = target.tolist()
        peak = max(map(abs, values))
        if peak > self._small_demand and all(v == v for v in values):
            unit = target / peak  # finite even for a 1e308 demand (target / scale would not be)
            reach = np.abs(unit / self._scale).max()  # |target| / S = reach * peak
            if reach > _MAX_DEMAND / peak:  # keep the direction, drop the absurd magnitude
                shrunk: FloatArray = unit * (_MAX_DEMAND / reach)
                return shrunk
        return target

    def bounds(
        self,
        u_prev: FloatArray,
        dead: BoolArray,
        probe_limit: FloatArray | None = None,
        step: FloatArray | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """(lo, hi), each (m,) in N: Omega(u_prev) with the ``dead`` thrusters held at 0 (or
        within +-probe_limit when probed); ``step`` (m,) overrides the per-cycle rate limit."""
        live = ~dead
        u_min = self._u_min * live
        u_max = self._u_max * live
        if probe_limit is not None and any(probe_limit.tolist()):
            probing = dead & (probe_limit > 0)
            u_min = np.where(probing, np.maximum(self._u_min, -probe_limit), u_min)
            u_max = np.where(probing, np.minimum(self._u_max, probe_limit), u_max)
        return command_bounds(u_min, u_max, self._step if step is None else step, u_prev)

    def allocate(
        self,
        tau_d: FloatArray,
        delta_hat: FloatArray,
        bf_hat: FloatArray,
        u_prev: FloatArray,
        u_pref: FloatArray | None = None,
        probe_limit: FloatArray | None = None,
        dt_s: float | None = None,
    ) -> Allocation:
        """Allocate the demanded wrench ``tau_d`` (k,) to thruster forces (N).

        ``delta_hat`` (m,) effectiveness estimates in [0, 1]; ``bf_hat`` (k,) estimated bias
        wrench B f_hat; ``u_prev`` (m,) the command now on the actuators (centre of the rate
        box); ``u_pref`` (m,) preferred command (excitation), None for zero; ``probe_limit``
        (m,) amplitude a dead thruster may use while probed; ``dt_s`` time since ``u_prev``
        was sent, when it differs from the configured period. A non-finite ``tau_d`` is
        allocated as zero demand (``INVALID_DEMAND``); never raises for numerical outcomes.
        """
        step = self._step
        if dt_s is not None:
            if dt_s != self._step_at[0]:
                self._step_at = (dt_s, self._thrusters.max_step(dt_s))
            step = self._step_at[1]
        status = AllocationStatus.OK
        # Python floats on the short vectors below: numpy's reductions cost several times more
        tau_d = np.asarray(tau_d, dtype=np.float64)
        if not all(map(math.isfinite, tau_d.tolist())):
            tau_d = np.zeros_like(bf_hat)
            status = AllocationStatus.INVALID_DEMAND
        dead = delta_hat < self.config.dead_threshold
        any_dead = True in dead.tolist()
        if any_dead:
            lo, hi = self.bounds(u_prev, dead, probe_limit, step)
        else:
            lo, hi = command_bounds(self._u_min, self._u_max, step, u_prev)
        beff, H = self._effective(delta_hat)
        target = self._shrunk(tau_d - bf_hat)
        g = beff.T @ (self._qs * target)
        g = -g if u_pref is None else -g - self._ru * u_pref
        D = self._D
        sol = self._solver.solve(H, g * D, lo / D, hi / D)
        if sol.found:
            u = sol.x * D
        else:
            u = np.clip(np.linalg.pinv(beff) @ target, lo, hi)
            u = np.where(np.isfinite(u), u, np.clip(0.0, lo, hi))
            status = AllocationStatus.FALLBACK if status is AllocationStatus.OK else status
        planned = beff @ u + bf_hat
        saturated = (u - lo <= self._tol) | (hi - u <= self._tol)
        if any_dead:
            saturated &= ~dead
        return Allocation(u, planned, tau_d - planned, saturated, dead, status, sol.iterations)
