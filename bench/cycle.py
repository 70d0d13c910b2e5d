"""Benchmark: cost of one allocator cycle (estimate + allocate), 4 thrusters.

Replays the (demand, measured wrench, truth) sequence of a closed-loop run of a scenario
through fresh cores, so every variant sees the same inputs, and times ``FtcapCore.step``.
Baseline in the same process: the same allocation QP solved by a per-call
``qpsolvers.solve_qp`` (what a naive implementation does each cycle).

    python bench/cycle.py [SCENARIO] [--json FILE]

Prints median / p99 per variant and the ratios to the baseline.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.cycle import FtcapCore
from ftcap_hil.core.faults import Truth
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.offline import run_mode


def replay_inputs(sc_name: str):  # type: ignore[no-untyped-def]
    sc = load_scenario(sc_name)
    rec = run_mode(sc, Mode.FTCAP)
    c = rec.columns
    k, m = sc.B.shape
    tau_d = np.column_stack([c[f"v_dem_{j}"] for j in range(1, k + 1)])
    x = np.column_stack([c[s] for s in sc.plant.state_labels])
    w = [None] + [sc.plant.measured_wrench(x[i - 1], x[i], sc.dt_s) for i in range(1, len(x))]
    truth = [
        Truth(
            np.array([c[f"delta_{i}"][n] for i in range(1, m + 1)]),
            np.array([c[f"f_{i}"][n] for i in range(1, m + 1)]),
        )
        for n in range(len(x))
    ]
    return sc, tau_d, w, truth


def time_core(sc, mode: Mode, backend: str, tau_d, w, truth) -> np.ndarray:  # type: ignore[no-untyped-def]
    cfg = dataclasses.replace(
        sc.core, mode=mode, allocator=dataclasses.replace(sc.core.allocator, backend=backend)
    )
    core = FtcapCore(sc.B, sc.thrusters, sc.dt_s, cfg)
    out = np.empty(len(tau_d))
    for n in range(len(tau_d)):
        t0 = time.perf_counter()
        core.step(tau_d[n], w[n], truth[n])
        out[n] = time.perf_counter() - t0
    return out * 1e6


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenario", nargs="?", default="paper-4.2-ex1")
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args()
    sc, tau_d, w, truth = replay_inputs(args.scenario)
    variants = {
        "ftcap/proxqp": (Mode.FTCAP, "proxqp"),
        "ftcap/daqp": (Mode.FTCAP, "daqp"),
        "cap/proxqp": (Mode.CAP, "proxqp"),
        "baseline: ftcap/qpsolvers.solve_qp(proxqp) per call": (Mode.FTCAP, "qpsolvers:proxqp"),
    }
    rows = {}
    for name, (mode, backend) in variants.items():
        us = time_core(sc, mode, backend, tau_d, w, truth)
        rows[name] = {"median_us": float(np.median(us)), "p99_us": float(np.percentile(us, 99))}
    base = rows["baseline: ftcap/qpsolvers.solve_qp(proxqp) per call"]["median_us"]
    print(f"{args.scenario}: {len(tau_d)} cycles, m = {sc.thrusters.m}")
    for name, r in rows.items():
        r["ratio_to_baseline"] = r["median_us"] / base
        print(
            f"  {name:55s} median {r['median_us']:7.1f} us  p99 {r['p99_us']:7.1f} us  "
            f"x{r['ratio_to_baseline']:.2f} of baseline"
        )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


if __name__ == "__main__":
    main()
