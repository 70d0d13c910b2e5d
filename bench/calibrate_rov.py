"""Fit the ROV's drives' diagnosis (bands, thresholds) on healthy holds (calibration seeds).

    python bench/calibrate_rov.py [--vehicle bluerov2-heavy] [--seeds 1001 1002 1003]
                                  [--seconds 120]

The same fit as the surface presets' (``bench/calibrate_shaft.py``: speed bands through the
binned 99.5th percentiles, current bands, ``cusum_h`` and ``load_h`` 1.5 x the largest
healthy CUSUM peaks), on healthy station holds of the vehicle (``ftcap_hil.runtime.
rov_hold``, mode ``drives``, nothing faulty, with the repositionings of :data:`MOVES`) in
each of :data:`CURRENTS` on the tuning
seeds 1001-1003 (the seed is the drives' telemetry noise and calibration errors; the table
in docs/vessels.md is judged on seeds 0-4), the diagnosis started at ``SETTLE_S`` once the
hold has settled, as in the judged runs (started with a hold at rest in a current, its
speed maps learn the in-flow too slowly: docs/vessels.md).
Loosened while fitting (no alarm trips, the
default bands decide what is commanded), so the result does not depend on the values being
fitted. It prints the ``[diagnosis]`` table for the vehicle file: the committed values are
exactly what it prints.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ftcap_hil.config.underwater import load_vehicle
from ftcap_hil.core.estimation.shaft import ResidualSample
from ftcap_hil.core.estimation.shaft_types import DiagnosisConfig
from ftcap_hil.runtime.rov_hold import hold

# NED currents (m/s) the holds are flown in: still water, ahead, abeam, and a stronger one
# from the quarter, so that every thruster runs both ways and at several speeds
CURRENTS = ((0.0, 0.0, 0.0), (0.2, 0.0, 0.0), (0.0, 0.25, 0.0), (-0.3, -0.3, 0.0))
# and in each, a pilot's repositioning once settled: 1.5 m ahead and 1 m deeper turning
# 60 deg, then back 1 m to port turning to -45 deg (the thrusters cross their range and the
# in-flow changes, as after a fault's reallocation)
MOVES = (
    (45.0, (1.5, 0.0, 6.0, 0.0, 0.0, math.radians(60.0))),
    (80.0, (1.5, -1.0, 5.0, 0.0, 0.0, math.radians(-45.0))),
)
TUNING_SEEDS = (1001, 1002, 1003)
SETTLE_S = 20.0
KEYS = ("band_rel", "band_res", "current_rel", "current_abs", "cusum_h", "load_h")


def _surface_fit() -> Any:
    """``fit`` of bench/calibrate_shaft.py (the one fit for every vehicle)."""
    path = Path(__file__).with_name("calibrate_shaft.py")
    spec = importlib.util.spec_from_file_location("ftcap_calibrate_shaft", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclass looks itself up by module name
    spec.loader.exec_module(module)
    return module.fit


def calibrate(
    vehicle_name: str = "bluerov2-heavy",
    seeds: Sequence[int] = TUNING_SEEDS,
    seconds: float = 120.0,
    currents: Sequence[tuple[float, float, float]] = CURRENTS,
) -> dict[str, float]:
    """The fitted ``[diagnosis]`` values, the hours and runs they rest on."""
    vehicle = load_vehicle(vehicle_name)
    base = DiagnosisConfig()
    loose = dataclasses.replace(
        vehicle.diagnosis, cusum_h=1e9, load_h=1e9, band_rel=base.band_rel,
        band_res=base.band_res, current_rel=base.current_rel, current_abs=base.current_abs,
    )  # fmt: skip
    traces: list[list[ResidualSample]] = []
    for seed in seeds:
        for current in currents:
            trace: list[ResidualSample] = []
            hold(vehicle, "drives", seconds=seconds, fault_s=seconds, current_ned=current,
                 seed=seed, diagnosis=loose, trace=trace, settle_s=SETTLE_S,
                 moves=MOVES)  # fmt: skip
            traces.append(trace)
    out: dict[str, float] = _surface_fit()(traces, loose.speed_resolution)
    out["hours"] = len(traces) * (seconds - SETTLE_S) / 3600.0  # what was fitted
    out["runs"] = len(traces)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--vehicle", default="bluerov2-heavy")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(TUNING_SEEDS))
    ap.add_argument("--seconds", type=float, default=120.0)
    args = ap.parse_args()
    out = calibrate(args.vehicle, args.seeds, args.seconds)
    print(f"# {args.vehicle}: {out['runs']} healthy holds, {out['hours']:.2f} h, seeds "
          f"{' '.join(map(str, args.seeds))}; largest healthy CUSUM {out['peak']:.3g} "
          f"(load {out['load_peak']:.3g}); the largest loss a healthy amplitude "
          f"showed {100.0 * out['loss']:.1f} %")  # fmt: skip
    print("[diagnosis]")
    for key in KEYS:
        if key in out:
            print(f"{key} = {out[key]:.4g}")


if __name__ == "__main__":
    main()
