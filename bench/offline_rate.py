"""Benchmark: the offline loop's throughput, simulated seconds per second.

A campaign's throughput is that of ``runtime.offline.run_mode``: the controller, the
allocator core, the truth (the paper's plant, or sim/'s realistic truth) and the recorder,
one control period after another. Each round runs every scenario once (mode ``ftcap``,
seed 1) and reports simulated seconds per second of the process's CPU time (what a Dask
worker's core delivers; less sensitive to other work on the machine than the wall clock)
and per wall-clock second, and the time inside ``FtcapCore.step`` as a share of the run.

    python bench/offline_rate.py [SCENARIO ...] [--rounds 3] [--json FILE]

Before/after figures come from alternating runs of two trees (PYTHONPATH=<tree>), each
pair's ratio being the figure to quote (docs/performance.md).
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
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.offline import run_mode

DEFAULT = ("paper-4.2-ex1", "cybership2-station")


def one_run(name: str) -> dict[str, float]:
    """One ``ftcap`` run of ``name`` (seed 1): sim-s per CPU-s and per wall-s, core share."""
    sc = dataclasses.replace(load_scenario(name), seed=1)
    c0, t0 = time.process_time(), time.perf_counter()
    rec = run_mode(sc, Mode.FTCAP)
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    sim_s = sc.steps * sc.dt_s
    core_s = float(np.sum(rec.columns["solve_us"])) * 1e-6
    return {"sim_per_cpu_s": sim_s / cpu, "sim_per_wall_s": sim_s / wall,
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
