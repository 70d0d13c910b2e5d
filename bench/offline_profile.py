"""Benchmark: where the offline loop's time goes, per stage (issue 31, item 1).

One ``ftcap`` run of each scenario (seed 1) under cProfile. Every function's own time is
charged to a stage by the file it lives in; time spent in numpy, the QP solver or the
standard library is charged to the stage of the project code that called it (split
between callers as cProfile measured it, up the call graph until project code is
reached). The stages:

* truth: the rigid body and its integrator, the environment's current and wind (sim/truth,
  sim/vessel, sim/environment, sim/live_truth, core/models);
* waves: the wave synthesis (sim/waves);
* drives: the thrusters' physics and their telemetry (sim/thrusters, sim/shaft,
  sim/feedback, sim/esc_model, sim/sampling);
* sensors: the pose and velocity sensors (sim/sensors);
* the drives' diagnosis (core/estimation/shaft*), the Kalman filter, its decisions, the rest
  of the estimation (core/estimation);
* allocation: building and solving the QP, the excitation (core/allocation);
* core, other: the cycle, the evidence and the rest of core/;
* recording: the run's record (report/);
* loop: the offline loop itself, the controller and the scenario (runtime/, config/).

    python bench/offline_profile.py [SCENARIO ...] [--json FILE]

Shares, not absolute times: cProfile's own overhead inflates the many short calls.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import json
import pstats
from collections import defaultdict
from pathlib import Path
from typing import Any

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.offline import run_mode

DEFAULT = ("cybership2-station", "supply-station")
ROOT = Path(__file__).resolve().parents[1]
STAGES = (
    ("waves", ("sim/waves.py",)),
    ("drives", ("sim/thrusters.py", "sim/shaft.py", "sim/feedback.py", "sim/esc_model.py",
                "sim/sampling.py")),
    ("sensors", ("sim/sensors.py",)),
    ("truth", ("sim/", "ftcap_hil/core/models/")),
    ("drives' diagnosis", ("ftcap_hil/core/estimation/shaft",)),
    ("Kalman filter", ("ftcap_hil/core/estimation/kalman",)),
    ("decisions", ("ftcap_hil/core/estimation/decisions",)),
    ("estimation, other", ("ftcap_hil/core/estimation/",)),
    ("allocation", ("ftcap_hil/core/allocation/", "ftcap_hil/core/effectiveness/")),
    ("core, other", ("ftcap_hil/core/",)),
    ("recording", ("ftcap_hil/report/",)),
    ("loop", ("ftcap_hil/",)),
)  # fmt: skip
Func = tuple[str, int, str]


def stage_of(filename: str) -> str | None:
    """The stage of a project file, None for anything else (numpy, the standard library)."""
    try:
        rel = Path(filename).resolve().relative_to(ROOT).as_posix()
    except ValueError:
        return None
    for name, prefixes in STAGES:
        if rel.startswith(prefixes):
            return name
    return None


def shares(stats: pstats.Stats) -> dict[str, float]:
    """Seconds per stage: own time where it is spent, other code's up to its project caller."""
    entries: dict[Func, Any] = stats.stats  # type: ignore[attr-defined]
    out: dict[str, float] = defaultdict(float)

    def charge(func: Func, seconds: float, depth: int = 0) -> None:
        stage = stage_of(func[0])
        if stage is not None:
            out[stage] += seconds
            return
        callers = entries[func][4] if func in entries else {}
        total = sum(v[2] + 0.0 for v in callers.values()) if callers else 0.0
        if depth > 20 or not callers or total <= 0.0:
            out["unattributed"] += seconds
            return
        for caller, (_cc, _nc, tt, _ct) in callers.items():
            charge(caller, seconds * tt / total, depth + 1)

    for func, (_cc, _nc, tt, _ct, _callers) in entries.items():
        if tt > 0.0:
            charge(func, tt)
    return dict(out)


def profile(name: str) -> dict[str, Any]:
    sc = dataclasses.replace(load_scenario(name), seed=1)
    prof = cProfile.Profile()
    prof.enable()
    run_mode(sc, Mode.FTCAP)
    prof.disable()
    by = shares(pstats.Stats(prof))
    total = sum(by.values())
    return {
        "scenario": name,
        "simulated_s": sc.steps * sc.dt_s,
        "profiled_s": total,
        "shares": {k: v / total for k, v in sorted(by.items(), key=lambda kv: -kv[1])},
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scenarios", nargs="*", default=list(DEFAULT))
    p.add_argument("--json", type=Path, help="also write the results here")
    args = p.parse_args()
    results = [profile(name) for name in args.scenarios]
    stages = [name for name, _ in STAGES] + ["unattributed"]
    print("| stage | " + " | ".join(r["scenario"] for r in results) + " |")
    print("|---|" + "---|" * len(results))
    for stage in stages:
        cells = [f"{100 * r['shares'].get(stage, 0.0):.1f} %" for r in results]
        print(f"| {stage} | " + " | ".join(cells) + " |")
    sims = [f"{r['simulated_s']:.0f} s in {r['profiled_s']:.1f} s" for r in results]
    print("| simulated, profiled | " + " | ".join(sims) + " |")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
