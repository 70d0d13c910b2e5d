"""Study: estimation and tracking under velocity measurement noise (closed loop).

Runs a scenario (default example 1) with white noise of each given standard deviation on
the measured body velocities (u, v, r) and reports, per mode and fault phase, the deviation
from the `none` run of the same scenario with the same noise sequence (RMS, m) and the
estimation error: max over thrusters of |delta_hat - delta|, averaged over the second half of
the phase (after the transient).

    python bench/noise.py [SCENARIO] [--std 0 1e-5 1e-4 1e-3] [--seeds 3] [--json FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import numpy as np

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.scenario import Scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.report.records import phase_metrics
from ftcap_hil.runtime.offline import run_mode

VARIANTS: dict[str, tuple[Mode, dict[str, object]]] = {
    "cap": (Mode.CAP, {}),
    "ftcap": (Mode.FTCAP, {}),
    "ftcap prefilter 0.3": (Mode.FTCAP, {"prefilter": 0.3}),
    "oracle": (Mode.ORACLE, {}),
}


def with_noise(sc: Scenario, std: float, seed: int, estimator: dict[str, object]) -> Scenario:
    noise = np.zeros(len(sc.plant.state_labels))
    for i, name in enumerate(sc.plant.state_labels):
        if name in ("u", "v", "r"):
            noise[i] = std
    core = dataclasses.replace(
        sc.core, estimator=dataclasses.replace(sc.core.estimator, **estimator)
    )
    return dataclasses.replace(sc, noise_std=noise, seed=seed, core=core)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenario", nargs="?", default="paper-4.2-ex1")
    ap.add_argument("--std", type=float, nargs="+", default=[0.0, 1e-5, 1e-4, 1e-3])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args()
    base = load_scenario(args.scenario)
    phases = base.phases()
    rows = []
    for std in args.std:
        for seed in range(args.seeds):
            none = run_mode(with_noise(base, std, seed, {}), Mode.NONE)
            for name, (mode, est) in VARIANTS.items():
                rec = run_mode(with_noise(base, std, seed, est), mode)
                for a, b in phases:
                    pm = phase_metrics(rec, none, a, b)
                    t = rec.t
                    late = (t >= (a + b) / 2) & (t < b)
                    m = base.thrusters.m
                    dh = np.column_stack([rec.columns[f"delta_hat_{i}"] for i in range(1, m + 1)])
                    d = np.column_stack([rec.columns[f"delta_{i}"] for i in range(1, m + 1)])
                    derr = float(np.abs(dh - d)[late].max(axis=1).mean())
                    rows.append(
                        {
                            "std": std,
                            "seed": seed,
                            "variant": name,
                            "phase": f"{a:g}-{b:g}",
                            "deviation_rms": pm["deviation_rms"],
                            "delta_error_late": derr,
                        }
                    )
    print(
        f"{args.scenario}: deviation RMS (m) / late delta_hat error, mean of {args.seeds} seeds\n"
    )
    print("| velocity noise | phase | " + " | ".join(VARIANTS) + " |")
    print("|---|---|" + "---|" * len(VARIANTS))
    for std in args.std:
        for a, b in phases:
            ph = f"{a:g}-{b:g}"
            cells = []
            for name in VARIANTS:
                sel = [
                    r for r in rows if r["std"] == std and r["variant"] == name and r["phase"] == ph
                ]
                dev = np.mean([r["deviation_rms"] for r in sel])
                derr = np.mean([r["delta_error_late"] for r in sel])
                cells.append(f"{dev:.4f} / {derr:.2f}")
            print(f"| {std:g} | {ph} | " + " | ".join(cells) + " |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


if __name__ == "__main__":
    main()
