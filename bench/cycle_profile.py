"""Profile: where one allocator cycle spends its time, per function (issue 25, item 1).

Replays bench/cycle_floor.py's problems (the paper's example 1, m thrusters) into a fresh
default core (Kalman estimator, daqp) under cProfile, once with no new estimation sample in
any cycle (estimates held: what a cycle between samples costs) and once with a sample in
every cycle, and prints a markdown table per case: each function's own time and its time
with callees, per cycle, and as a share of the cycle. Then the same cases without the
profiler, each stage timed by a clock around it (inclusive: the QP solve inside allocate,
daqp inside the solve), as means per cycle and as ratios to the pinv + clip + slew floor
called in the same cycles.

    python bench/cycle_profile.py [--m 4] [--seconds 700] [--top 16] [--kind kalman]

cProfile's own cost per call (~0.1-0.3 us) inflates the many small functions, so the
shares, not the microseconds, are the figure to read (bench/cycle_floor.py has the
uninstrumented times); numpy's ufuncs and array methods appear under their own names.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cycle_floor import Problems, callers, make_core, split_scenario

import ftcap_hil.core.cycle as cycle_module
from ftcap_hil.core.cycle import FtcapCore

ROOT = str(Path(__file__).resolve().parents[1])


def _name(key: tuple[str, int, str]) -> str:
    path, line, func = key
    if path == "~":
        return func
    short = path.replace(ROOT + "/", "").replace(".py", "")
    if "site-packages" in short:
        short = short.split("site-packages/")[1]
    return f"{short}:{func}"


def profile(p: Problems, kind: str, sampled: bool) -> pstats.Stats:
    """The replay of every cycle after the tenth under cProfile (module docstring)."""
    core = make_core(p.sc, kind)
    for n in range(10):  # a filter that has seen some data
        core.step(p.tau_d[n], p.obs[n], p.truth[n])
    prof = cProfile.Profile()
    prof.enable()
    for n in range(10, p.n):
        core.step(p.tau_d[n], p.obs[n] if sampled else None, p.truth[n])
    prof.disable()
    return pstats.Stats(prof)


def table(stats: pstats.Stats, cycles: int, top: int) -> list[str]:
    """Markdown rows: the ``top`` functions by own time, per cycle (us) and share."""
    raw = stats.stats  # type: ignore[attr-defined]
    total = sum(v[2] for v in raw.values())
    rows = sorted(raw.items(), key=lambda kv: kv[1][2], reverse=True)[:top]
    out = [
        f"cycle under cProfile: {total / cycles * 1e6:.0f} us",
        "",
        "| function | calls / cycle | own us / cycle | own share | with callees us / cycle |",
        "|---|---|---|---|---|",
    ]
    for key, (_cc, nc, tt, ct, _callers) in rows:
        out.append(
            f"| `{_name(key)}` | {nc / cycles:.2f} | {tt / cycles * 1e6:.1f} | "
            f"{tt / total:.1%} | {ct / cycles * 1e6:.1f} |"
        )
    return out


def _timed(obj: Any, name: str, acc: dict[str, float], label: str) -> None:
    """Wrap ``obj.name`` (an instance attribute from now on) in a clock adding to acc."""
    inner: Callable[..., Any] = getattr(obj, name)
    clock = time.perf_counter

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t0 = clock()
        try:
            return inner(*args, **kwargs)
        finally:
            acc[label] += clock() - t0

    setattr(obj, name, wrapper)


class _DaqpProxy:
    """daqp's module as the solver sees it, its ``solve`` timed."""

    def __init__(self, module: Any, acc: dict[str, float]) -> None:
        self.solve = module.solve
        _timed(self, "solve", acc, "daqp.solve itself")


def instrument(core: FtcapCore, acc: dict[str, float]) -> None:
    """Clocks around the cycle's stages (module docstring)."""
    stage: Any = core.stage
    if hasattr(stage, "filter"):
        _timed(stage.filter, "update", acc, "Kalman filter update")
        _timed(stage.filter, "_predict", acc, "  its prediction")
        _timed(stage._decider, "update", acc, "decisions")
    elif hasattr(stage, "_estimator"):
        _timed(stage._estimator, "update", acc, "windowed estimator update")
    _timed(cycle_module, "apply_evidence", acc, "evidence applied")
    _timed(core, "_excite", acc, "excitation")
    _timed(core.allocator, "allocate", acc, "allocate")
    solver: Any = core.allocator._solver
    _timed(solver, "solve", acc, "  QP solve (daqp wrapper)")
    if hasattr(solver, "_daqp"):
        solver._daqp = _DaqpProxy(solver._daqp, acc)


def stage_table(p: Problems, kind: str, sampled: bool) -> list[str]:
    """Markdown rows: each stage's mean time per cycle and its ratio to pinv's."""
    acc: dict[str, float] = {"pinv": 0.0, "cycle (FtcapCore.step)": 0.0}
    acc |= dict.fromkeys(
        ["Kalman filter update", "  its prediction", "decisions", "windowed estimator update",
         "evidence applied", "excitation", "allocate", "  QP solve (daqp wrapper)",
         "daqp.solve itself"], 0.0,
    )  # fmt: skip
    core = make_core(p.sc, kind)
    for n in range(10):
        core.step(p.tau_d[n], p.obs[n], p.truth[n])
    unwrapped = cycle_module.apply_evidence
    instrument(core, acc)
    pinv, clock = callers(p)["pinv"], time.perf_counter
    try:
        for n in range(10, p.n):
            t0 = clock()
            pinv(n)
            t1 = clock()
            core.step(p.tau_d[n], p.obs[n] if sampled else None, p.truth[n])
            acc["pinv"] += t1 - t0
            acc["cycle (FtcapCore.step)"] += clock() - t1
    finally:
        cycle_module.apply_evidence = unwrapped  # type: ignore[assignment]
    cycles, floor = p.n - 10, acc["pinv"]
    out = ["| stage | us / cycle (mean) | ratio to pinv |", "|---|---|---|"]
    for label, total in acc.items():
        if total > 0.0:
            out.append(f"| {label} | {total / cycles * 1e6:.1f} | x{total / floor:.2f} |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--m", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=700.0)
    ap.add_argument("--top", type=int, default=16)
    ap.add_argument("--kind", default="kalman", choices=["kalman", "windowed"])
    args = ap.parse_args()
    p = Problems(split_scenario(args.m, args.seconds))
    for sampled in (False, True):
        what = "a new sample every cycle" if sampled else "no new sample"
        print(f"### m = {args.m}, {args.kind}, {what} ({p.n - 10} cycles)\n")
        print("\n".join(table(profile(p, args.kind, sampled), p.n - 10, args.top)))
        print("\nthe same, stages timed without the profiler:\n")
        print("\n".join(stage_table(p, args.kind, sampled)))
        print()
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
