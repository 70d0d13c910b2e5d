"""Fault decisions from an estimate and its variance: what is flagged, what the allocator uses.

A point estimate that dips is not evidence. Every decision here compares the estimate with a
threshold at a confidence of ``z_flag`` standard deviations (one-sided), with hysteresis:

* **what the allocator uses**: for a thruster reported faulty (below), its estimate;
  otherwise the most optimistic effectiveness the data allow,
  delta_alloc_i = min(1, delta_hat_i + z_use sigma_i), and 1 while that loss is below
  ``practical_loss``: where the estimator is unsure the allocation is CAP's for that
  thruster, and it moves to the estimate as the evidence grows. A healthy thruster is only
  taken out (delta_alloc < dead_threshold) when even its upper bound says it is dead.
  ``in_use``: delta_alloc_i < 1.
* **faulty** (reported: flags, STATUSTEXT): delta_hat_i + z sigma_i < fault_threshold;
  cleared when delta_hat_i - z sigma_i > fault_threshold. **removed** (delta_alloc = 0, so
  it gets nothing but recovery probes): faulty (established at z_flag) and its estimate
  below ``removal_threshold``: a thruster at a third of its thrust or less is not worth
  commanding three times harder, and that steady command carries little information
  (delta_i u_i at a steady command looks like a bias); back once delta_hat_i - z_use
  sigma_i > removal_threshold.
* **observable now** (reported): the Fisher information of the last ``window`` samples
  alone would give delta_i a standard deviation below ``observable_std``. Where it is not,
  the estimate holds (see ``core/estimation/kalman.py``) while its variance grows, so the
  bounds above
  keep every decision as it is and the allocation drifts back to CAP's: nothing drifts.
* **bias**: the estimated generalized bias b = B f + tau_env mixes thruster biases with the
  environment (current, wind, mean wave drift) and model error, which only the controller
  should answer. A healthy-time baseline b_0 follows b while no bias is attributed: it
  starts once b is known to within the smallest bias acted upon, is the running mean of b
  at first, then follows it with the time constant ``bias_base_s``; a change b - b_0 is
  attributed to thruster i when it lies along that thruster's column B_i (the residual off
  it, or off the columns of several thrusters taken greedily, is consistent with zero at
  the 0.1 % level; else nothing is attributed), is significant (|f_i| > z sigma_fi) and is at least
  ``bias_min_rel`` of the thruster's range. Only attributed biases are compensated
  (``bf_alloc``); the rest stays with the controller, as in CAP.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.estimation.config import BiasCompensation, EstimatorConfig
from ftcap_hil.core.estimation.kalman import FilterOutput, inv_small
from ftcap_hil.core.frozen import fast_init
from ftcap_hil.core.messages import BoolArray, FloatArray

# chi^2 quantiles at 0.999 for 0..3 degrees of freedom (bias attribution residual).
_CHI2_999 = (0.0, 10.83, 13.82, 16.27)


@fast_init  # built every cycle (core/frozen.py)
@dataclass(frozen=True)
class Decision:
    """What the allocator is to use and what is reported, per thruster (m,) or wrench (k,)."""

    delta_alloc: FloatArray  # (m,) effectiveness handed to the allocator
    f_alloc: FloatArray  # (m,) attributed per-thruster bias (N), 0 where none
    bf_alloc: FloatArray  # (k,) B f_alloc
    in_use: BoolArray  # (m,) the allocator uses less than 1
    removed: BoolArray  # (m,) taken out of the allocation (delta_alloc = 0)
    faulty: BoolArray  # (m,) reported fault (effectiveness)
    bias_faulty: BoolArray  # (m,) a bias is attributed to this thruster
    observable: BoolArray  # (m,) the recent data determine delta_i
    info: FloatArray | None = None  # (m,) the Fisher information this sample carried


class FaultDecider:
    """Turns filter outputs into :class:`Decision` s (module docstring)."""

    def __init__(
        self,
        B: FloatArray,
        u_range: FloatArray,
        config: EstimatorConfig,
        fault_threshold: float,
        fault_clear: float,
    ) -> None:
        self._B = np.asarray(B, dtype=np.float64)
        self._k, self._m = self._B.shape
        self._range = np.asarray(u_range, dtype=np.float64)
        self.config = config
        self._threshold = fault_threshold
        self._clear = fault_clear
        m = self._m
        self._info = np.zeros((config.window, m))
        self._head = 0
        self._in_use = np.zeros(m, dtype=bool)
        self._removed = np.zeros(m, dtype=bool)
        self._faulty = np.zeros(m, dtype=bool)
        self._bias_on = np.zeros(m, dtype=bool)
        self._f = np.zeros(m)
        self._base: FloatArray | None = None
        self._samples = 0
        self._base_var = np.zeros((self._k, self._k))
        self._eps = 1e-18 * np.eye(self._k)  # keeps the attribution's weight invertible
        self._range_min = float(np.min(self._range))

    def forget(self, which: BoolArray) -> None:
        """The thrusters ``which`` (m,) neither flagged nor removed, with no recent data (the
        filter's :meth:`~KalmanEstimator.forget`)."""
        self._faulty = self._faulty & ~which
        self._removed = self._removed & ~which
        self._info = np.where(which, 0.0, self._info)

    def update(self, out: FilterOutput, dt_s: float) -> Decision:
        """Decisions after one filter update of an estimation interval ``dt_s``."""
        self._info[self._head] = out.info
        self._head = (self._head + 1) % self._info.shape[0]
        observable = self._info.sum(axis=0) * self.config.observable_std**2 >= 1.0
        est = out.estimate
        sigma = np.sqrt(np.maximum(out.delta_var, 0.0))
        if not out.alarm:
            # The sample that raised a change alarm usually straddles the onset, and every
            # suspect of the alarm moves on it: flags and removals wait for the filter's own
            # estimate of the next sample (a co-suspect was flagged for one cycle otherwise).
            self._effectiveness(est.delta_hat, sigma)
        self._bias(est.bf_hat, out.bias_cov, dt_s, out.alarm)
        # An established fault: the estimate itself (0 once removed); otherwise the
        # optimistic bound.
        optimistic = self._optimistic(est.delta_hat, sigma)
        delta_alloc = np.where(self._faulty, est.delta_hat, optimistic)
        delta_alloc = np.where(self._removed, 0.0, delta_alloc)
        self._in_use = delta_alloc < 1.0
        f = np.where(self._bias_on, self._f, 0.0)
        bf = est.bf_hat if self.config.bias_compensation is BiasCompensation.ALL else self._B @ f
        # the state arrays are replaced, never written in place: handed out without copies
        return Decision(
            delta_alloc, f, bf, self._in_use, self._removed, self._faulty, self._bias_on,
            observable, out.info,
        )  # fmt: skip

    def _optimistic(self, d: FloatArray, sigma: FloatArray) -> FloatArray:
        upper = np.minimum(1.0, d + self.config.z_use * sigma)
        out: FloatArray = np.where(1.0 - upper < self.config.practical_loss, 1.0, upper)
        return out

    def _effectiveness(self, d: FloatArray, sigma: FloatArray) -> None:
        """Bounds, not point estimates: an unobserved thruster's growing variance keeps its
        flag as it is (neither bound crosses the threshold)."""
        z = self.config.z_flag
        hi, lo = d + z * sigma, d - z * sigma
        flag_on, flag_off = hi < self._threshold, lo > self._threshold
        self._faulty = (self._faulty | flag_on) & ~flag_off
        # Removed (taken out of the allocation): a reported fault that is confidently weak, or
        # whose estimate is below the dead threshold; back only once it is confidently
        # stronger than that (no flicker around it).
        zu, weak = self.config.z_use, self.config.removal_threshold
        gone = d < weak
        alive = d - zu * sigma > weak
        self._removed = self._faulty & ((self._removed | gone) & ~alive)

    def _bias(self, b: FloatArray, cov: FloatArray, dt_s: float, alarm: bool) -> None:
        # The baseline moves only while b is known to within the smallest bias acted upon
        # (not in the re-convergence after a change alarm, when a fault's bias would leak in).
        small = self.config.bias_min_rel * self._range_min
        # max(diag) < small^2 (a NaN: not settled), in Python floats
        settled = not alarm and all(v < small**2 for v in cov.diagonal().tolist())
        if self._base is None:
            if settled:
                self._base, self._base_var, self._samples = b.copy(), cov.copy(), 1
            return
        self._samples += 1
        if True not in self._bias_on.tolist() and settled:
            # the running mean of the samples so far at first, then the time constant
            a = min(1.0, max(dt_s / self.config.bias_base_s, 1.0 / self._samples))
            self._base = self._base + a * (b - self._base)
            self._base_var = (1.0 - a) ** 2 * self._base_var + a**2 * cov
        delta_b = b - self._base
        sigma = cov + self._base_var + self._eps
        self._attribute(delta_b, inv_small(sigma))

    def _attribute(self, delta_b: FloatArray, w: FloatArray) -> None:
        """Greedy: the thruster whose column explains most of delta_b, then the rest."""
        z, dof = self.config.z_flag, self._k - 1
        # No single column can explain more than the whole change: below the (hysteresis)
        # level nothing can be attributed, the common case of healthy operation.
        need_min = 0.5 * z if True in self._bias_on.tolist() else z
        if float(delta_b @ w @ delta_b) < need_min**2:
            self._bias_on, self._f = np.zeros(self._m, dtype=bool), np.zeros(self._m)
            return
        limit = _CHI2_999[min(dof, 3)] if dof > 0 else 0.0
        keep_on = self._bias_on.copy()
        on = np.zeros(self._m, dtype=bool)
        f_all = np.zeros(self._m)
        rest = delta_b.copy()
        c = self._B
        cwc = np.einsum("ji,jl,li->i", c, w, c)
        # what the greedy steps share, computed once; the per-thruster tests in Python floats
        cwc_floor = np.maximum(cwc, 1e-300)
        root = np.sqrt(cwc).tolist()
        need = np.where(keep_on, 0.5 * z, z).tolist()  # hysteresis: half the level to stay on
        big_at = (self.config.bias_min_rel * self._range).tolist()
        for _ in range(self._m):
            f = (c.T @ (w @ rest)) / cwc_floor
            i = _best(f.tolist(), root, need, big_at, on.tolist())
            if i < 0:
                break
            rest = rest - c[:, i] * f[i]
            on[i], f_all[i] = True, f[i]
            if dof == 0 or float(rest @ w @ rest) < limit:
                self._bias_on, self._f = on, f_all
                return
        # Nothing found, or what is left is not along any thruster (the environment or the
        # model changed): attribute nothing, the controller keeps it.
        self._bias_on, self._f = np.zeros(self._m, dtype=bool), np.zeros(self._m)


def _best(
    f: list[float], root: list[float], need: list[float], big_at: list[float], on: list[bool]
) -> int:
    """The greedy step's pick: among the thrusters not yet on whose score |f_i| root_i
    exceeds need_i and whose |f_i| reaches big_at_i, the first of the largest score; -1 if
    none. (numpy's (score > need) & (|f| >= big) & ~on, then argmax of the scores where
    that holds, in Python floats: the same comparisons, a NaN never qualifying.)"""
    best, index = -math.inf, -1
    for i, fi in enumerate(f):
        size = abs(fi)
        score = size * root[i]
        if score > need[i] and size >= big_at[i] and not on[i] and score > best:
            best, index = score, i
    return index
