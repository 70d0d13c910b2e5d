"""Benchmark: the offline loop's throughput, simulated seconds per wall-clock second.

A campaign's throughput is that of ``runtime.offline.run_mode``: the controller, the
allocator core, the truth (the paper's plant, or sim/'s realistic truth) and the recorder,
one control period after another. Each round runs every scenario once (mode ``ftcap``,
seed 1) and, just before each, a fixed reference workload: 2000 cycles of a pinv + clip +
slew allocator on the paper vessel (bench/cycle_floor.py's floor). The load-independent
figure is the wall time of one simulated second in those reference cycles.

    python bench/offline_rate.py [SCENARIO ...] [--rounds 3] [--json FILE]

Prints, per scenario, min / median / max over the rounds of sim-s per wall-s and of the
wall time per simulated second in pinv cycles, the time inside ``FtcapCore.step`` as a
share of the run, and the load average.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from typing import Any

import numpy as np

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.effectiveness.geometry import effectiveness, paper_four_thrusters
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.offline import run_mode

DEFAULT = ("paper-4.2-ex1", "cybership2-station")
REFERENCE_CYCLES = 2000


def reference_s() -> float:
    """Wall time of REFERENCE_CYCLES pinv + clip + slew allocations (paper vessel)."""
    ts = paper_four_thrusters()
    B_pinv = np.linalg.pinv(effectiveness(ts))
    u_min, u_max, step = ts.u_min, ts.u_max, ts.max_step(0.2827)
    tau = np.random.default_rng(0).normal(0.0, 0.1, size=(REFERENCE_CYCLES, 3))
    u = np.zeros(ts.m)
    t0 = time.perf_counter()
    for n in range(REFERENCE_CYCLES):
        lo = np.maximum(u_min, u - step)
        hi = np.minimum(u_max, u + step)
        u = np.minimum(np.maximum(B_pinv @ tau[n], lo), hi)
    return time.perf_counter() - t0


def one_run(name: str) -> dict[str, float]:
    """One ``ftcap`` run of ``name`` (seed 1): its wall time, simulated time, core time."""
    sc = dataclasses.replace(load_scenario(name), seed=1)
    ref = reference_s()
    t0 = time.perf_counter()
    rec = run_mode(sc, Mode.FTCAP)
    wall = time.perf_counter() - t0
    sim_s = sc.steps * sc.dt_s
    core_s = float(np.sum(rec.columns["solve_us"])) * 1e-6
    per_sim_s = wall / sim_s / (ref / REFERENCE_CYCLES)
    return {"sim_per_wall": sim_s / wall, "pinv_cycles_per_sim_s": per_sim_s,
            "core_share": core_s / wall}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenarios", nargs="*", default=list(DEFAULT))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    runs: dict[str, list[dict[str, float]]] = {n: [] for n in args.scenarios}
    for _ in range(args.rounds):
        for name in args.scenarios:
            runs[name].append(one_run(name))
    out: dict[str, Any] = {}
    for name, rs in runs.items():
        out[name] = {key: [r[key] for r in rs] for key in rs[0]}
        print(f"{name}:")
        for key, vals in out[name].items():
            print(f"  {key:24s} {min(vals):10.2f} / {np.median(vals):10.2f} / {max(vals):10.2f}")
    print(f"(min / median / max over {args.rounds} rounds; load average {load0:.2f} -> "
          f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores)")  # fmt: skip
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=2)


if __name__ == "__main__":
    main()
