"""Box-constrained QP workspaces, persistent across cycles.

    minimize   1/2 x^T H x + g^T x
    subject to lo <= x <= hi                      (H: n x n, symmetric positive definite)

A failed solve is data (``BoxQpSolution.found = False``), never an exception. Backends:

* ``proxqp``: one ``proxsuite.proxqp.dense.QP`` with native box constraints, warm-started
  from the previous result. proxsuite 0.8 segfaults when ``initial_guess`` is changed after
  ``init()`` or when ``update()`` precedes the first ``solve()``: the option is set before
  ``init()`` and the first problem is solved immediately.
* ``daqp`` (the default, ``AllocatorConfig.backend``): the dual active-set solver through its
  C entry point (no persistent object in its Python API, but a call is cheap).
* ``qpsolvers:<name>``: a one-shot ``qpsolvers.solve_qp`` per call. Slower (it rebuilds the
  problem each time); used as the cross-check in tests and as the benchmark baseline.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ftcap_hil.core.frozen import fast_init
from ftcap_hil.core.messages import FloatArray

_BIG = 1e20  # stands for an infinite bound in backends that want finite numbers


@fast_init  # built every cycle (core/frozen.py)
@dataclass(frozen=True)
class BoxQpSolution:
    """A solve's outcome: ``x`` (n,) inside [lo, hi] when ``found``, else whatever the
    backend returned (possibly NaN), and the backend's iteration count."""

    x: FloatArray
    found: bool
    iterations: int = 0


class BoxQpSolver(Protocol):
    """A box-QP backend (module docstring); ``name`` as given to :func:`make_solver`."""

    name: str

    def solve(self, H: FloatArray, g: FloatArray, lo: FloatArray, hi: FloatArray) -> BoxQpSolution:
        """Minimize 1/2 x^T H x + g^T x over lo <= x <= hi; H (n, n), g, lo, hi (n,)."""
        ...


def _accepted(
    x: FloatArray, lo: FloatArray, hi: FloatArray, tol: float, iterations: int = 0
) -> BoxQpSolution:
    """x clipped to [lo, hi] if it is finite and inside [lo - tol, hi + tol], else not found
    (a NaN propagates through maximum/minimum and fails the comparison). minimum(maximum())
    rather than np.clip: the same result, cheaper on short vectors."""
    clipped = np.minimum(np.maximum(x, lo), hi)
    # max |x - clipped| <= tol, a NaN failing it; Python's all() over the list is several
    # times cheaper than a numpy reduction on (m,)
    if all(d <= tol for d in np.abs(x - clipped).tolist()):
        return BoxQpSolution(clipped, True, iterations)
    return BoxQpSolution(x, False, iterations)


class ProxqpBoxSolver:
    """One persistent proxsuite dense QP of size ``n``, warm-started (module docstring)."""

    name = "proxqp"

    def __init__(self, n: int, eps_abs: float = 1e-9, max_iter: int = 1000) -> None:
        from proxsuite import proxqp

        self._proxqp = proxqp
        self._n = n
        self._eps_abs = eps_abs
        self._max_iter = max_iter
        self._qp: Any = None  # proxsuite.proxqp.dense.QP, untyped
        self._H = np.zeros((n, n))  # the H the workspace holds
        self._H_tol = 0.0  # a new H closer than this (max abs difference) is not passed
        self._solved = proxqp.QPSolverOutput.PROXQP_SOLVED

    def _fresh(self, H: FloatArray, g: FloatArray, lo: FloatArray, hi: FloatArray) -> None:
        proxqp = self._proxqp
        qp = proxqp.dense.QP(self._n, 0, 0, True)
        qp.settings.initial_guess = proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
        qp.settings.eps_abs = self._eps_abs
        qp.settings.eps_rel = 0.0
        qp.settings.max_iter = self._max_iter
        qp.settings.max_iter_in = 200  # default 1500: a hopeless solve would take seconds
        # Without it a warm start after a bounds-only update may return its stale x.
        qp.settings.check_duality_gap = True
        qp.settings.verbose = False
        qp.init(H, g, None, None, None, None, None, lo, hi)
        qp.solve()
        self._qp = qp
        self._H = H
        self._H_tol = 1e-9 * np.abs(H).max()

    def solve(self, H: FloatArray, g: FloatArray, lo: FloatArray, hi: FloatArray) -> BoxQpSolution:
        """Warm-started solve (as :meth:`BoxQpSolver.solve`); cold restart if it fails."""
        if self._qp is not None:
            # proxsuite re-does its set-up whenever H is passed: only pass an H that changed
            # (the allocator hands back the very same array while delta_hat holds still).
            Hn = None
            if H is not self._H and np.abs(H - self._H).max() > self._H_tol:
                Hn = self._H = H
                self._H_tol = 1e-9 * np.abs(H).max()
            self._qp.update(Hn, g, None, None, None, None, None, lo, hi)
            self._qp.solve()
            sol = self._result(lo, hi)
            if sol.found:
                return sol
        # No workspace yet, or the warm start stalled: a cold start from a fresh workspace.
        self._fresh(H, g, np.maximum(lo, -_BIG), np.minimum(hi, _BIG))
        sol = self._result(lo, hi)
        if not sol.found:
            self._qp = None
        return sol

    def _result(self, lo: FloatArray, hi: FloatArray) -> BoxQpSolution:
        res = self._qp.results
        info = res.info
        x = res.x.copy()
        if info.status != self._solved:
            return BoxQpSolution(x, False, info.iter)
        return _accepted(x, lo, hi, 1e-7, info.iter)


def _bound_size(hi: FloatArray, lo: FloatArray) -> float:
    """max(1, the largest |bound| below _BIG; a NaN one left out). In Python floats: several
    times cheaper than numpy's masked reduction on (m,)."""
    size = 1.0
    for b in hi.tolist() + lo.tolist():
        if size < abs(b) < _BIG:
            size = abs(b)
    return size


class DaqpBoxSolver:
    """daqp's dual active-set solver for box QPs of size ``n`` (no persistent workspace)."""

    name = "daqp"

    # daqp's own primal feasibility tolerance (its default): an answer it reports optimal
    # may sit this far outside a bound, so acceptance uses the same figure (relative to the
    # bounds' size), then clips. A stricter acceptance threw optimal answers away.
    PRIMAL_TOL = 1e-6

    def __init__(self, n: int) -> None:
        import daqp

        self._daqp = daqp
        self._n = n
        self._A = np.zeros((0, n))
        self._sense = np.zeros(n, dtype=np.int32)

    def solve(self, H: FloatArray, g: FloatArray, lo: FloatArray, hi: FloatArray) -> BoxQpSolution:
        """One daqp call (as :meth:`BoxQpSolver.solve`); infinite bounds become +-1e20."""
        hi_f, lo_f = np.minimum(hi, _BIG), np.maximum(lo, -_BIG)
        x, _fval, exitflag, info = self._daqp.solve(
            H, g, self._A, hi_f, lo_f, self._sense, primal_tol=self.PRIMAL_TOL
        )
        x = np.asarray(x, dtype=np.float64)
        iterations = int(info.get("iterations", 0)) if isinstance(info, dict) else 0
        if exitflag < 1:
            return BoxQpSolution(x, False, iterations)
        return _accepted(x, lo, hi, self.PRIMAL_TOL * _bound_size(hi_f, lo_f), iterations)


class QpsolversBoxSolver:
    """Per-call ``qpsolvers.solve_qp``: the baseline, not for the hot loop."""

    def __init__(self, n: int, solver: str) -> None:
        import qpsolvers

        self._solve_qp = qpsolvers.solve_qp
        self._solver = solver
        self.name = f"qpsolvers:{solver}"

    def solve(self, H: FloatArray, g: FloatArray, lo: FloatArray, hi: FloatArray) -> BoxQpSolution:
        """One ``qpsolvers.solve_qp`` call (as :meth:`BoxQpSolver.solve`), tolerance 1e-5."""
        x = self._solve_qp(H, g, lb=lo, ub=hi, solver=self._solver)
        if x is None:
            return BoxQpSolution(np.full_like(g, np.nan), False)
        # One-shot defaults are looser than our workspaces.
        return _accepted(np.asarray(x, dtype=np.float64), lo, hi, 1e-5)


_BACKENDS: dict[str, Callable[[int], BoxQpSolver]] = {
    "proxqp": ProxqpBoxSolver,
    "daqp": DaqpBoxSolver,
}


def available_backends() -> list[str]:
    """Backend names :func:`make_solver` accepts here (the qpsolvers ones as installed)."""
    import qpsolvers

    return sorted(_BACKENDS) + [f"qpsolvers:{s}" for s in qpsolvers.available_solvers]


def make_solver(backend: str, n: int) -> BoxQpSolver:
    """``proxqp`` | ``daqp`` | ``qpsolvers:<solver>``; ValueError names an unknown backend."""
    if backend.startswith("qpsolvers:"):
        import qpsolvers

        solver = backend.split(":", 1)[1]
        if solver not in qpsolvers.available_solvers:
            raise ValueError(
                f"qp backend {backend!r}: solver not installed (have {qpsolvers.available_solvers})"
            )
        return QpsolversBoxSolver(n, solver)
    try:
        return _BACKENDS[backend](n)
    except KeyError:
        raise ValueError(
            f"qp backend {backend!r}: unknown (choose from {available_backends()})"
        ) from None
