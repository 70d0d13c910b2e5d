"""The drives' diagnosis against motion only, one fault per cause (docs/diagnosis.md's table).

    python bench/shaft_cases.py [--seed 0]

CyberShip II station keeping (the shipped scenario: its preset's drives and telemetry, the
allocator told a data sheet off by K_T +5 %, K_Q +8 %, lag +25 %), the starboard propeller
failing at 60 s with each cause, flown with the drives' telemetry and without it (motion
only). Prints a Markdown table: isolation delay, deviation max, delta-hat at the end.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the cases live with the tests

from ftcap_hil.core.faults import Cause  # noqa: E402
from ftcap_hil.core.status import Mode  # noqa: E402
from ftcap_hil.runtime.offline import run_mode  # noqa: E402
from tests.support.shaft_cases import cs2_case, deviation_max, flags, isolation_s  # noqa: E402

STARBOARD = 1
CASES = [
    (Cause.HEALTHY, 1.0), (Cause.DRIVE_DEAD, 0.0), (Cause.JAMMED, 0.0), (Cause.STUCK, 1.0),
    (Cause.WEAK_MOTOR, 0.5), (Cause.LOST_BLADE, 0.5), (Cause.TELEMETRY_LOST, 1.0),
    (Cause.POWER_LOST, 0.0), (Cause.HULL_LOSS, 0.5),
]  # fmt: skip


def _iso(rec: object, cause: Cause) -> str:
    if cause is Cause.HEALTHY or cause is Cause.TELEMETRY_LOST:
        return "never flagged" if not flags(rec).any() else "flagged"  # type: ignore[arg-type]
    s = isolation_s(rec, STARBOARD, 60.0)  # type: ignore[arg-type]
    return "never" if math.isinf(s) else f"{s:.1f} s"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print("| cause | isolation, drives + motion | isolation, motion only "
          "| deviation max (drives / motion) | delta_hat at 120 s (drives / motion) |")  # fmt: skip
    print("|---|---|---|---|---|")
    for cause, delta in CASES:
        label = cause.value + ("" if delta in (0.0, 1.0) else f" {delta:g}")
        recs = [run_mode(cs2_case(STARBOARD, cause, delta, seed=args.seed, shaft=s), Mode.FTCAP)
                for s in (True, False)]  # fmt: skip
        dh = [float(r.columns[f"delta_hat_{STARBOARD + 1}"][-1]) for r in recs]
        dev = [deviation_max(r) for r in recs]
        print(f"| {label} | {_iso(recs[0], cause)} | {_iso(recs[1], cause)} "
              f"| {dev[0]:.3f} / {dev[1]:.3f} m | {dh[0]:.2f} / {dh[1]:.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()
