"""Benchmark: one allocator cycle against the floor, a pinv + clip + slew allocator (issue 25).

Every variant is called on the same problems, interleaved one call each in turn within a
cycle, so that a change of machine load hits them all alike; the figures are ratios of
each variant's median to the pinv allocator's median of the same round, never absolute
times alone (they are printed beside the ratios, with the load average).

    python bench/cycle_floor.py [--m 4 8 16] [--rounds 5] [--seconds 700] [--json FILE]

The problems: the paper's example 1 (section 4.2, its faults at 12 s and 200 s) flown
offline once per m by the default F-TCAP core, its m thrusters the paper's four, each
split into m / 4 thrusters at the same place, turned 0.1 rad apart (the faults given to
each part). That run's demands, measured states and truths are replayed into:

* ``pinv``: u = clip(B^+ tau_d, Omega(u_prev)), B^+ computed once: what PX4 and most DP
  code do;
* ``raw daqp``: ``daqp.solve`` on the very QPs (H, g, bounds) the reference run's allocator
  built;
* ``allocate``: ``Allocator.allocate`` (daqp) on the reference run's arguments;
* ``step, no sample``: ``FtcapCore.step`` with no new estimation sample (estimates held);
* ``step + sample, kalman`` / ``windowed``: a new sample every call, each estimator.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from collections.abc import Callable
from typing import Any

import daqp
import numpy as np

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.allocation.allocator import Allocator
from ftcap_hil.core.cycle import FtcapCore
from ftcap_hil.core.effectiveness.geometry import ThrusterSet, effectiveness
from ftcap_hil.core.estimation.config import EstimatorKind
from ftcap_hil.core.estimation.stages import Observation
from ftcap_hil.core.faults import FaultEvent, FaultSchedule, Truth
from ftcap_hil.core.scenario import Scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.offline import run_mode, told_sensor_noise

VARIANTS = (
    "pinv",
    "raw daqp",
    "allocate",
    "step, no sample",
    "step + sample, kalman",
    "step + sample, windowed",
)


def split_scenario(m: int, seconds: float) -> Scenario:
    """Example 1 with each of its 4 thrusters split into m / 4 (module docstring)."""
    sc = told_sensor_noise(load_scenario("paper-4.2-ex1"))
    reps = m // 4
    if reps * 4 != m:
        raise SystemExit(f"--m: a multiple of 4, got {m}")
    parts = tuple(
        dataclasses.replace(t, name=f"{t.name}.{r}", angle_rad=t.angle_rad + 0.1 * r)
        for t in sc.thrusters.thrusters
        for r in range(reps)
    )
    thrusters = ThrusterSet(parts)

    def split(v: Any) -> Any:
        return None if v is None else np.repeat(np.asarray(v, dtype=np.float64), reps)

    events = tuple(
        dataclasses.replace(e, delta=split(e.delta), bias=split(e.bias))
        if e.thruster is None
        else FaultEvent(e.start, e.end, None, None, None)  # not used by example 1
        for e in sc.faults.events
    )
    return dataclasses.replace(
        sc,
        thrusters=thrusters,
        B=effectiveness(thrusters),
        faults=FaultSchedule(m, events),
        duration_s=min(seconds, sc.duration_s),
    )


class Problems:
    """The reference run's inputs per cycle, and what its allocator was called with."""

    def __init__(self, sc: Scenario) -> None:
        self.sc = sc
        self.alloc_args: list[tuple[Any, ...]] = []
        self.qps: list[tuple[np.ndarray, ...]] = []
        rec = run_mode(sc, Mode.FTCAP, on_core=self._spy)
        c, (k, m) = rec.columns, sc.B.shape
        self.tau_d = np.column_stack([c[f"v_dem_{j}"] for j in range(1, k + 1)])
        x = np.column_stack([c[s] for s in sc.plant.state_labels])
        self.obs = [None] + [Observation(x[i - 1], x[i], sc.dt_s) for i in range(1, len(x))]
        self.truth = [
            Truth(
                np.array([c[f"delta_{i}"][n] for i in range(1, m + 1)]),
                np.array([c[f"f_{i}"][n] for i in range(1, m + 1)]),
            )
            for n in range(len(x))
        ]
        self.n = len(x)

    def _spy(self, core: FtcapCore) -> None:
        """Record every allocate call's arguments and every QP handed to the solver."""
        alloc, solver = core.allocator, core.allocator._solver
        allocate, solve = alloc.allocate, solver.solve

        def spy_allocate(*args: Any) -> Any:
            self.alloc_args.append(tuple(a.copy() if hasattr(a, "copy") else a for a in args))
            return allocate(*args)

        def spy_solve(H: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> Any:
            self.qps.append((H.copy(), g.copy(), lo.copy(), hi.copy()))
            return solve(H, g, lo, hi)

        alloc.allocate = spy_allocate  # type: ignore[method-assign]
        solver.solve = spy_solve  # type: ignore[method-assign]


def make_core(sc: Scenario, kind: str) -> FtcapCore:
    """A fresh default core (daqp) of the scenario with the estimator ``kind``."""
    est = dataclasses.replace(sc.core.estimator, kind=EstimatorKind(kind))
    cfg = dataclasses.replace(sc.core, mode=Mode.FTCAP, estimator=est)
    return FtcapCore(sc.B, sc.thrusters, sc.dt_s, cfg, sc.plant)


def callers(p: Problems) -> dict[str, Callable[[int], Any]]:
    """One function per variant, called with the cycle's index."""
    sc = p.sc
    B_pinv = np.linalg.pinv(sc.B)
    u_min, u_max = sc.thrusters.u_min, sc.thrusters.u_max
    step = sc.thrusters.max_step(sc.dt_s)
    state = {"u": np.zeros(sc.thrusters.m)}

    def pinv(n: int) -> None:
        u_prev = state["u"]
        lo = np.maximum(u_min, u_prev - step)
        hi = np.minimum(u_max, u_prev + step)
        state["u"] = np.minimum(np.maximum(B_pinv @ p.tau_d[n], lo), hi)

    A, sense = np.zeros((0, sc.thrusters.m)), np.zeros(sc.thrusters.m, dtype=np.int32)

    def raw_daqp(n: int) -> None:
        H, g, lo, hi = p.qps[n % len(p.qps)]
        daqp.solve(H, g, A, hi, lo, sense, primal_tol=1e-6)

    alloc = Allocator(sc.B, sc.thrusters, sc.dt_s, make_core(sc, "kalman").scale)
    held = make_core(sc, "kalman")
    for n in range(10):  # a filter that has seen some data, then held
        held.step(p.tau_d[n], p.obs[n], p.truth[n])
    kalman, windowed = make_core(sc, "kalman"), make_core(sc, "windowed")
    return {
        "pinv": pinv,
        "raw daqp": raw_daqp,
        "allocate": lambda n: alloc.allocate(*p.alloc_args[n % len(p.alloc_args)]),
        "step, no sample": lambda n: held.step(p.tau_d[n], None, p.truth[n]),
        "step + sample, kalman": lambda n: kalman.step(p.tau_d[n], p.obs[n], p.truth[n]),
        "step + sample, windowed": lambda n: windowed.step(p.tau_d[n], p.obs[n], p.truth[n]),
    }


def one_round(p: Problems) -> dict[str, float]:
    """Median time (us) per variant over one pass of the problems, interleaved."""
    calls = callers(p)
    times = {name: np.empty(p.n) for name in VARIANTS}
    clock = time.perf_counter
    for n in range(p.n):
        for name in VARIANTS:
            f = calls[name]
            t0 = clock()
            f(n)
            times[name][n] = clock() - t0
    return {name: float(np.median(t)) * 1e6 for name, t in times.items()}


# Issue 25's targets, ratios to pinv: (m, variant, at most)
TARGETS = (
    ("4", "step, no sample", 5.0),
    ("16", "step, no sample", 8.0),
    ("4", "step + sample, kalman", 20.0),
    ("16", "step + sample, kalman", 25.0),
)


def print_targets(out: dict[str, Any]) -> None:
    """Each of issue 25's targets whose m was run: the median ratio against the limit."""
    for m, variant, limit in TARGETS:
        if m in out:
            ratio = float(np.median(out[m]["ratio_to_pinv"][variant]))
            verdict = "met" if ratio <= limit else "not met"
            print(f"target: {variant} at m = {m} <= x{limit:g}: x{ratio:.2f} ({verdict})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--m", type=int, nargs="+", default=[4, 8, 16])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=700.0, help="of example 1 (<= 700)")
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    out: dict[str, Any] = {}
    for m in args.m:
        p = Problems(split_scenario(m, args.seconds))
        rounds = [one_round(p) for _ in range(args.rounds)]
        ratios = {v: [r[v] / r["pinv"] for r in rounds] for v in VARIANTS}
        us = {v: [r[v] for r in rounds] for v in VARIANTS}
        out[str(m)] = {"cycles": p.n, "ratio_to_pinv": ratios, "median_us": us}
        print(f"m = {m}: {p.n} cycles x {args.rounds} rounds; ratio to pinv (min/median/max"
              " over rounds), median us:")  # fmt: skip
        for v in VARIANTS:
            r = ratios[v]
            print(
                f"  {v:26s} x{min(r):6.2f} / x{np.median(r):6.2f} / x{max(r):6.2f}"
                f"   {np.median(us[v]):7.1f} us"
            )
    print_targets(out)
    print(f"load average {load0:.2f} -> {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=2)


if __name__ == "__main__":
    main()
