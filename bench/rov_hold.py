"""The BlueROV2 Heavy holding station with a thruster faulty: the allocation told
(``oracle``), not told (``cap``), or told by the thruster's own drive (``drives``).

    python bench/rov_hold.py [--vehicle bluerov2-heavy] [--seeds 0 1 2 3 4]

Every thruster in turn meets each of :data:`KINDS` at 30 s of a 60 s hold at 5 m depth,
heading north, in a 0.2 m/s current to the north (``ftcap_hil.runtime.rov_hold``; the
drives' diagnosis starts on the settled hold at 20 s). ``drives`` runs on each evaluation
seed (the telemetry's noise; the diagnosis was calibrated on seeds 1001-1003 by
``bench/calibrate_rov.py``); ``oracle`` and ``cap`` do not read the telemetry and run once.
Prints two markdown tables: per fault kind, the drives' isolation and the alarms they raise
on healthy thrusters; per fault kind and mode, what the hold keeps. The tables in
docs/vessels.md are this command's output.
"""

from __future__ import annotations

import argparse
import math
import statistics

from ftcap_hil.config.underwater import load_vehicle
from ftcap_hil.runtime.rov_hold import HoldResult, hold

KINDS = ("dead", "jammed", "fouled", "power-lost")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--vehicle", default="bluerov2-heavy")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    args = ap.parse_args()
    vehicle = load_vehicle(args.vehicle)
    m = vehicle.thrusters.m
    healthy = [hold(vehicle, "drives", seed=s) for s in args.seeds]
    runs: dict[tuple[str, str], list[HoldResult]] = {}
    for kind in KINDS:
        runs[kind, "drives"] = [hold(vehicle, "drives", i, kind, seed=s)
                                for i in range(m) for s in args.seeds]  # fmt: skip
        for mode in ("oracle", "cap"):
            runs[kind, mode] = [hold(vehicle, mode, i, kind) for i in range(m)]
    fa = sum(r.false_alarms for r in healthy)
    print(f"Healthy holds, drives' diagnosis: {fa} false alarms in {len(healthy)} runs "
          f"({len(healthy) * 40 / 60:.0f} min judged).\n")  # fmt: skip
    print("| fault | runs | isolated <= 1 s | <= 2 s | never | median delay (s) "
          "| runs with an alarm on a healthy thruster | alarms per run |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for kind in KINDS:
        rs = runs[kind, "drives"]
        delays = [r.isolated_s for r in rs if not math.isnan(r.isolated_s)]
        n = len(rs)
        share = [sum(d <= lim for d in delays) / n for lim in (1.0, 2.0)]
        med = f"{statistics.median(delays):.2f}" if delays else "-"
        print(f"| {kind} | {n} | {share[0]:.0%} | {share[1]:.0%} | {(n - len(delays)) / n:.0%} "
              f"| {med} | {sum(r.false_alarms > 0 for r in rs) / n:.0%} "
              f"| {sum(r.false_alarms for r in rs) / n:.2f} |")  # fmt: skip
    print(
        "\n| fault | allocator | runs | depth dev. max (cm), median / worst "
        "| roll/pitch max (deg), median / worst | heading dev. max (deg), median / worst |"
    )
    print("|---|---|---|---|---|---|")
    for kind in KINDS:
        for mode in ("oracle", "drives", "cap"):
            rs = runs[kind, mode]
            cols = [[r.depth_dev_max_m * 100 for r in rs], [r.roll_pitch_max_deg for r in rs],
                    [r.heading_dev_max_deg for r in rs]]  # fmt: skip
            cells = " | ".join(f"{statistics.median(c):.2f} / {max(c):.2f}" for c in cols)
            print(f"| {kind} | {mode} | {len(rs)} | {cells} |", flush=True)


if __name__ == "__main__":
    main()
