"""Benchmark: cost of one allocator cycle (estimate + allocate), 4 thrusters.

Replays the (demand, measured state, truth) sequence of a closed-loop run of a scenario
through fresh cores, so every variant sees the same inputs, and times ``FtcapCore.step``.
The variants run interleaved, one cycle each in turn, so that a change of machine load
hits them all alike. Baselines in the same process: the windowed estimator (the estimator
before the Kalman one) and the same allocation QP solved by a per-call
``qpsolvers.solve_qp`` (what a naive implementation does each cycle).

    python bench/cycle.py [SCENARIO] [--rounds N] [--json FILE]

Prints min / median / max over the rounds of each variant's median and p99, the ratios of
the medians to the windowed estimator and to the per-call baseline, and the load average.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time

import numpy as np

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.cycle import FtcapCore
from ftcap_hil.core.estimation.config import EstimatorKind
from ftcap_hil.core.estimation.stages import Observation
from ftcap_hil.core.faults import Truth
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.offline import run_mode, told_sensor_noise

VARIANTS = {
    "ftcap kalman/proxqp": (Mode.FTCAP, "kalman", "proxqp"),
    "ftcap kalman/daqp": (Mode.FTCAP, "kalman", "daqp"),
    "ftcap windowed/proxqp": (Mode.FTCAP, "windowed", "proxqp"),
    "cap/proxqp": (Mode.CAP, "kalman", "proxqp"),
    "baseline: windowed/qpsolvers.solve_qp(proxqp) per call": (
        Mode.FTCAP,
        "windowed",
        "qpsolvers:proxqp",
    ),
}


def replay_inputs(sc_name: str):  # type: ignore[no-untyped-def]
    sc = told_sensor_noise(load_scenario(sc_name))
    rec = run_mode(sc, Mode.FTCAP)
    c = rec.columns
    k, m = sc.B.shape
    tau_d = np.column_stack([c[f"v_dem_{j}"] for j in range(1, k + 1)])
    x = np.column_stack([c[s] for s in sc.plant.state_labels])
    obs = [None] + [Observation(x[i - 1], x[i], sc.dt_s) for i in range(1, len(x))]
    truth = [
        Truth(
            np.array([c[f"delta_{i}"][n] for i in range(1, m + 1)]),
            np.array([c[f"f_{i}"][n] for i in range(1, m + 1)]),
        )
        for n in range(len(x))
    ]
    return sc, tau_d, obs, truth


def make_core(sc, mode: Mode, kind: str, backend: str) -> FtcapCore:  # type: ignore[no-untyped-def]
    cfg = dataclasses.replace(
        sc.core,
        mode=mode,
        estimator=dataclasses.replace(sc.core.estimator, kind=EstimatorKind(kind)),
        allocator=dataclasses.replace(sc.core.allocator, backend=backend),
    )
    return FtcapCore(sc.B, sc.thrusters, sc.dt_s, cfg, sc.plant)


def one_round(sc, tau_d, obs, truth) -> dict[str, np.ndarray]:  # type: ignore[no-untyped-def]
    cores = {name: make_core(sc, *v) for name, v in VARIANTS.items()}
    out = {name: np.empty(len(tau_d)) for name in VARIANTS}
    for n in range(len(tau_d)):
        for name, core in cores.items():
            t0 = time.perf_counter()
            core.step(tau_d[n], obs[n], truth[n])
            out[name][n] = time.perf_counter() - t0
    return {name: us * 1e6 for name, us in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenario", nargs="?", default="paper-4.2-ex1")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args()
    sc, tau_d, obs, truth = replay_inputs(args.scenario)
    rounds = [one_round(sc, tau_d, obs, truth) for _ in range(args.rounds)]
    rows: dict[str, dict[str, list[float]]] = {}
    for name in VARIANTS:
        med = [float(np.median(r[name])) for r in rounds]
        p99 = [float(np.percentile(r[name], 99)) for r in rounds]
        to_windowed = [
            float(np.median(r[name]) / np.median(r["ftcap windowed/proxqp"])) for r in rounds
        ]
        base = "baseline: windowed/qpsolvers.solve_qp(proxqp) per call"
        to_base = [float(np.median(r[name]) / np.median(r[base])) for r in rounds]
        rows[name] = {"median_us": med, "p99_us": p99, "x_windowed": to_windowed}
        rows[name]["x_baseline"] = to_base
    print(f"{args.scenario}: {len(tau_d)} cycles x {args.rounds} rounds, m = {sc.thrusters.m},")
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; min/median/max:")
    for name, r in rows.items():
        cells = [f"{k} {min(v):.2f}/{np.median(v):.2f}/{max(v):.2f}" for k, v in r.items()]
        print(f"  {name:55s} " + "  ".join(cells))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


if __name__ == "__main__":
    main()
