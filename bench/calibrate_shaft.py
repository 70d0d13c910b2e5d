"""Fit the drives' diagnosis bands and test threshold on healthy runs (calibration seeds).

    python bench/calibrate_shaft.py [--seeds 1001 1002 1003] [--duration 600] [PRESET ...]

For each preset it flies the preset's shipped realistic scenarios healthy on the given
seeds (disjoint from the evaluation seeds of the campaign, which start at 1), with the
allocator told only the data sheet, and collects the raw residuals of every healthy,
commanded telemetry sample (ShaftDiagnoser.trace). Then, as PX4's replay tools tune a
detector on logs:

* **bands**: in bins of the predicted thrust (load current), the 99.5th percentile of the
  absolute error over 3 is the band there; a line through the bins (least squares, both
  coefficients >= 0) gives ``band_rel``, ``band_abs`` (``current_rel``, ``current_abs``);
* **threshold**: the CUSUM of the residuals in those bands, per thruster and run, and
  ``cusum_h`` = 1.5 x the largest healthy peak (at least 8): zero trips in the calibration
  hours, with margin.

It prints a ``[diagnosis]`` table per preset to paste into the preset file, with the seeds
and hours it was fitted on. Thresholds are never judged on these seeds.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections import defaultdict
from collections.abc import Sequence

import numpy as np

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.cycle import FtcapCore
from ftcap_hil.core.estimation.shaft import ResidualSample
from ftcap_hil.core.estimation.shaft_types import DiagnosisConfig
from ftcap_hil.core.faults import FaultSchedule
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.offline import run_mode

SCENARIOS = {
    "cybership2": ("cybership2-station", "cybership2-transit"),
    "supply": ("supply-station",),
}
LOOSE = {"band_rel": 0.05, "band_abs": 0.01, "current_rel": 0.05, "current_abs": 0.05}


def healthy_trace(name: str, seed: int, duration_s: float) -> tuple[list[ResidualSample], float]:
    """The residual trace of one healthy run (tests loosened: nothing trips, nothing
    resets) and the full forces of its thrusters."""
    sc = load_scenario(name)
    diag = dataclasses.replace(sc.core.diagnosis, cusum_h=1e9)
    sc = dataclasses.replace(
        sc, faults=FaultSchedule(sc.thrusters.m), seed=seed, duration_s=duration_s,
        core=dataclasses.replace(sc.core, diagnosis=diag),
    )  # fmt: skip
    trace: list[ResidualSample] = []

    def keep(core: FtcapCore) -> None:
        if core.shaft is not None:
            core.shaft.trace = trace

    run_mode(sc, Mode.FTCAP, on_core=keep)
    return trace, float(sc.duration_s)


def fit_band(x: np.ndarray, err: np.ndarray, scale: float) -> tuple[float, float]:
    """(rel, abs) of band = rel |x| + abs scale through the binned 99.5th percentiles / 3."""
    ok = np.isfinite(err)
    x, err = np.abs(x[ok]), np.abs(err[ok])
    edges = np.quantile(x, np.linspace(0.0, 1.0, 9))
    xs, ys = [], []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (x >= lo) & (x <= hi)
        if sel.sum() >= 20:
            xs.append(float(np.median(x[sel])))
            ys.append(float(np.quantile(err[sel], 0.995)) / 3.0)
    A = np.column_stack([xs, np.full(len(xs), scale)])
    coef, *_ = np.linalg.lstsq(A, np.array(ys), rcond=None)
    rel, ab = (max(float(c), 0.0) for c in coef)
    floor = max(ys) / 10.0 / scale  # never a band of zero
    return rel, max(ab, floor)


def cusum_peak(z: np.ndarray, k: float) -> float:
    """The largest value either one-sided CUSUM of ``z`` reaches."""
    low = high = peak = 0.0
    for v in z.tolist():
        low = max(0.0, low - v - k)
        high = max(0.0, high + v - k)
        peak = max(peak, low, high)
    return peak


def calibrate(preset: str, seeds: Sequence[int], duration_s: float) -> dict[str, float]:
    """The fitted ``[diagnosis]`` values of one preset, and how much data they rest on."""
    runs, hours, full = [], 0.0, None
    for name in SCENARIOS[preset]:
        sc = load_scenario(name)
        full = np.maximum(np.abs(sc.thrusters.u_min), np.abs(sc.thrusters.u_max))
        for seed in seeds:
            trace, dur = healthy_trace(name, seed, duration_s)
            runs.append(trace)
            hours += dur / 3600.0
    assert full is not None
    fit = _fit(runs, full)
    base = DiagnosisConfig()
    peaks = []
    for trace in runs:
        by = defaultdict(list)
        for s in trace:
            by[s.index].append(s)
        for i, samples in by.items():
            t = np.array([s.thrust_error_n for s in samples])
            x = np.array([s.thrust_n for s in samples])
            peaks.append(cusum_peak(t / (fit["band_rel"] * np.abs(x) + fit["band_abs"] * full[i]),
                                    base.cusum_k))  # fmt: skip
            e = np.array([s.load_error_a for s in samples])
            load = np.array([s.load_a for s in samples])
            ok = np.isfinite(e)
            if ok.any():
                band = fit["current_rel"] * load[ok] + fit["current_abs"]
                peaks.append(cusum_peak(e[ok] / band, base.cusum_k))
    fit["cusum_h"] = max(8.0, 1.5 * max(peaks))
    fit["hours"] = hours
    fit["peak"] = max(peaks)
    return fit


def _fit(runs: list[list[ResidualSample]], full: np.ndarray) -> dict[str, float]:
    samples = [s for trace in runs for s in trace]
    # thrust errors relative to each thruster's full force, pooled
    fi = np.array([full[s.index] for s in samples])
    x = np.array([s.thrust_n for s in samples]) / fi
    e = np.array([s.thrust_error_n for s in samples]) / fi
    band_rel, band_abs = fit_band(x, e, 1.0)
    load = np.array([s.load_a for s in samples])
    le = np.array([s.load_error_a for s in samples])
    current_rel, current_abs = fit_band(load, le, 1.0) if np.isfinite(le).sum() > 100 else (
        LOOSE["current_rel"], LOOSE["current_abs"])  # fmt: skip
    return {"band_rel": band_rel, "band_abs": band_abs, "current_rel": current_rel,
            "current_abs": current_abs}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("presets", nargs="*", default=list(SCENARIOS))
    ap.add_argument("--seeds", type=int, nargs="+", default=[1001, 1002, 1003])
    ap.add_argument("--duration", type=float, default=600.0)
    args = ap.parse_args()
    for preset in args.presets:
        fit = calibrate(preset, args.seeds, args.duration)
        print(f"# {preset}: fitted by bench/calibrate_shaft.py on seeds {args.seeds}, "
              f"{fit['hours']:.2f} h healthy ({', '.join(SCENARIOS[preset])}); "
              f"largest healthy CUSUM {fit['peak']:.1f}")  # fmt: skip
        print("[diagnosis]")
        for key in ("band_rel", "band_abs", "current_rel", "current_abs", "cusum_h"):
            print(f"{key} = {fit[key]:.4g}")
        print()


if __name__ == "__main__":
    main()
