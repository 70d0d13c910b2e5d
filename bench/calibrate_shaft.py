"""Fit the drives' diagnosis bands and test threshold on healthy runs (calibration seeds).

    python bench/calibrate_shaft.py [PRESET ...] [--campaign sweeps] [--seeds S ...]
                                    [--duration 600] [--workers 2] [--check]

For each preset it flies, healthy, every ``[[scenario]]`` of the campaign that the
thresholds are judged in (the sweeps campaign: CyberShip II in its three currents, the
supply vessel from Beaufort 2 to 6), on the campaign's ``tuning_seeds`` (disjoint from
its evaluation seeds; the planner refuses to evaluate on them) unless ``--seeds`` says
otherwise. Each seed goes into the scenario's ``[scenario] seed`` before the scenario is
read, so it draws the sea, the sensors' noise and the model error of that seed. The
allocator is told only the data sheet; every healthy telemetry sample of a shaft that
should be turning measurably is kept (ShaftDiagnoser.trace). Then, as PX4's replay tools
tune a detector on logs:

* **bands**: in bins of the predicted speed, in units of the telemetry's speed resolution
  (the preset's ``[diagnosis] speed_resolution``), the 99.5th percentile of the absolute
  speed error over 3 is the band there; a line through the bins (least squares, both
  coefficients >= 0) gives ``band_rel`` and ``band_res`` (at least half a step: a reading is
  known no better than its rounding); the same over the servos'
  deflections ``servo_band_rel`` and ``servo_band_res`` (where the preset has servos), and
  over the predicted load current ``current_rel`` and ``current_abs``;
* **thresholds**: the CUSUM of the residuals in those bands, per thruster and run, and
  ``cusum_h`` = 1.5 x the largest healthy peak of the speed's (at least 8), ``load_h`` the
  same of the load current's: zero trips in the calibration hours, with margin. The load
  drifts with the sea (inflow, ventilation) where the speed does not, so each test has
  its own.

* **amplitude**: ``amplitude_loss``, the largest loss a healthy actuator's amplitude showed
  (``ratio_t``, the force its speed shows over the predicted). An amplitude down by more
  than twice that (and by more than the data sheet's tolerance ``cal_limit``) for
  ``amplitude_hold_s`` is named ``weak`` without the speed test; a tripped speed test is
  named ``weak`` only where the amplitude is down by more than ``cal_limit``, and where
  healthy amplitudes dip below that, the speed test alone keeps a healthy drive from being
  named.

It prints a ``[diagnosis]`` table per preset to paste into the preset file, with the seeds
and hours it was fitted on: the committed values are exactly what it prints, and
``--check`` (run by CI) exits 1 naming every key where the preset file says otherwise (a
change to what the healthy runs do moves the fit: refit and commit). The runs are
independent: ``--workers`` processes fly them (the result does not depend on how many).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections import defaultdict
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from ftcap_hil.config.campaign import load_campaign
from ftcap_hil.config.presets import load_preset
from ftcap_hil.config.scenario import parse_scenario
from ftcap_hil.core.cycle import FtcapCore
from ftcap_hil.core.estimation.shaft import ResidualSample
from ftcap_hil.core.estimation.shaft_types import DiagnosisConfig
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.campaign_plan import _read, _with
from ftcap_hil.runtime.offline import run_mode

KEYS = (
    "band_rel",
    "band_res",
    "servo_band_rel",
    "servo_band_res",
    "current_rel",
    "current_abs",
    "cusum_h",
    "load_h",
    "amplitude_loss",
)
LOOSE_CURRENT = (0.05, 0.05)  # (current_rel, current_abs) where no load is visible


@dataclasses.dataclass(frozen=True)
class Flight:
    """One healthy calibration run: a campaign scenario (its document) on one seed."""

    preset: str
    label: str
    seed: int
    doc: dict


def flights(
    campaign: str, presets: Sequence[str], seeds: Sequence[int] | None, duration_s: float,
    labels: Sequence[str] | None = None,
) -> list[Flight]:  # fmt: skip
    """The healthy runs of ``presets`` in ``campaign`` (only ``labels`` if given), seed
    applied before anything is drawn."""
    spec = load_campaign(campaign)
    use = list(seeds) if seeds else list(spec.tuning_seeds)
    if not use:
        raise SystemExit(f"{spec.source}: no tuning_seeds; give --seeds")
    out = []
    for entry in spec.scenarios:
        if labels is not None and entry.label not in labels:
            continue
        doc = _read(entry, spec)
        preset = str(doc.get("plant", {}).get("preset", ""))
        if preset not in presets:
            continue
        doc["scenario"]["duration"] = duration_s
        out += [Flight(preset, entry.label, s, _with(doc, s, [])) for s in use]
    return out


def healthy_trace(flight: Flight) -> tuple[list[ResidualSample], float, float]:
    """The residual trace of one healthy run (tests loosened: nothing trips, nothing
    resets), its duration (s) and the telemetry resolution the diagnosis was told."""
    sc = parse_scenario(flight.doc, f"calibration {flight.label} seed {flight.seed}")
    # loosened, and with the default bands: what counts as commanded and what the online
    # calibration takes as quiet do not depend on the values being fitted (a fixed point)
    base = DiagnosisConfig()
    diag = dataclasses.replace(
        sc.core.diagnosis, cusum_h=1e9, load_h=1e9, band_rel=base.band_rel, band_res=base.band_res,
        servo_band_rel=base.servo_band_rel, servo_band_res=base.servo_band_res,
        current_rel=base.current_rel, current_abs=base.current_abs,
    )  # fmt: skip
    sc = dataclasses.replace(sc, core=dataclasses.replace(sc.core, diagnosis=diag))
    trace: list[ResidualSample] = []

    def keep(core: FtcapCore) -> None:
        if core.shaft is not None:
            core.shaft.trace = trace

    run_mode(sc, Mode.FTCAP, on_core=keep)
    return trace, float(sc.duration_s), diag.speed_resolution


def fit_band(x: np.ndarray, err: np.ndarray) -> tuple[float, float]:
    """(rel, abs) of band = rel |x| + abs through the binned 99.5th percentiles / 3."""
    ok = np.isfinite(err)
    x, err = np.abs(x[ok]), np.abs(err[ok])
    edges = np.unique(np.quantile(x, np.linspace(0.0, 1.0, 9)))
    xs, ys = [], []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (x >= lo) & (x <= hi)
        if sel.sum() >= 20:
            xs.append(float(np.median(x[sel])))
            ys.append(float(np.quantile(err[sel], 0.995)) / 3.0)
    A = np.column_stack([xs, np.ones(len(xs))])
    coef, *_ = np.linalg.lstsq(A, np.array(ys), rcond=None)
    rel, ab = (max(float(c), 0.0) for c in coef)
    return rel, max(ab, max(ys) / 10.0)  # never a band of zero


def cusum_peak(z: np.ndarray, k: float) -> float:
    """The largest value either one-sided CUSUM of ``z`` reaches."""
    low = high = peak = 0.0
    for v in z.tolist():
        low = max(0.0, low - v - k)
        high = max(0.0, high + v - k)
        peak = max(peak, low, high)
    return peak


def fit(traces: list[list[ResidualSample]], resolution: float) -> dict[str, float]:
    """The ``[diagnosis]`` values from healthy traces (one per run) of one preset: the
    shafts' speed bands, the servos' deflection bands (where the preset has servos), the
    load current's bands and the two thresholds."""
    samples = [s for trace in traces for s in trace]
    shafts = [s for s in samples if s.shaft]
    if len(shafts) < 200:
        raise SystemExit(f"{len(shafts)} healthy commanded samples: too few to fit a band")
    out: dict[str, float] = {}
    for prefix, group in (("", shafts), ("servo_", [s for s in samples if not s.shaft])):
        if len(group) >= 200:
            x = np.array([s.speed for s in group]) / resolution
            e = np.array([s.speed_error for s in group]) / resolution
            rel, res = fit_band(x, e)
            # never under half a step: a reading is known no better than its rounding (the
            # diagnosis floors it there too)
            out[prefix + "band_rel"], out[prefix + "band_res"] = rel, max(res, 0.5)
    load = np.array([s.load_a for s in shafts])
    le = np.array([s.load_error_a for s in shafts])
    current = fit_band(load, le) if np.isfinite(le).sum() > 100 else LOOSE_CURRENT
    out["current_rel"], out["current_abs"] = current
    out = {k: float(f"{v:.4g}") for k, v in out.items()}  # what is printed is what counts
    base = DiagnosisConfig()
    k, floor_z = base.cusum_k, base.floor_z
    peaks: list[float] = []  # the speed test's, per thruster and run
    load_peaks: list[float] = [0.0]  # the load test's (none where no load is visible)
    for trace in traces:
        by = defaultdict(list)
        for s in trace:
            by[s.index].append(s)
        for samples_i in by.values():
            prefix = "" if samples_i[0].shaft else "servo_"
            if prefix + "band_rel" not in out:
                continue  # too few samples to fit: the defaults, not judged here
            n = np.array([s.speed for s in samples_i])
            err = np.array([s.speed_error for s in samples_i])
            spread = np.array([s.speed_spread for s in samples_i])
            band = (out[prefix + "band_rel"] * np.abs(n) + spread
                    + out[prefix + "band_res"] * resolution)  # fmt: skip
            peaks.append(cusum_peak(err / band, k))
            le_i = np.array([s.load_error_a for s in samples_i])
            load_i = np.array([s.load_a for s in samples_i])
            band = out["current_rel"] * load_i + out["current_abs"]
            # the samples the load test takes with the fitted bands: a load floor_z of them
            ok = np.isfinite(le_i) & (load_i >= floor_z * band)
            if ok.any():
                load_peaks.append(cusum_peak(le_i[ok] / band[ok], k))
    out["cusum_h"] = float(f"{max(8.0, 1.5 * max(peaks)):.4g}")
    out["loss"] = max(0.0, 1.0 - min(s.ratio for s in samples))  # the healthy amplitudes'
    out["amplitude_loss"] = float(f"{out['loss']:.4g}")
    out["load_h"] = float(f"{max(8.0, 1.5 * max(load_peaks)):.4g}")
    out["peak"], out["load_peak"] = max(peaks), max(load_peaks)
    return out


def calibrate(
    preset: str, seeds: Sequence[int] | None, duration_s: float, campaign: str = "sweeps",
    workers: int = 1, labels: Sequence[str] | None = None,
) -> dict[str, float]:  # fmt: skip
    """The fitted ``[diagnosis]`` values of one preset, the hours and runs they rest on."""
    todo = flights(campaign, [preset], seeds, duration_s, labels)
    if not todo:
        raise SystemExit(f"campaign {campaign}: no scenario of preset {preset}")
    if workers > 1:
        with ProcessPoolExecutor(workers) as pool:
            done = list(pool.map(healthy_trace, todo))
    else:
        done = [healthy_trace(f) for f in todo]
    resolutions = {r for _, _, r in done}
    if len(resolutions) != 1:
        raise SystemExit(f"preset {preset}: scenarios tell different speed resolutions")
    out = fit([t for t, _, _ in done], resolutions.pop())
    out["hours"] = sum(d for _, d, _ in done) / 3600.0
    out["runs"] = len(done)
    return out


def differences(preset: str, fitted: dict[str, float]) -> list[str]:
    """Where ``preset``'s file says other than the fit (what the command printed)."""
    committed = load_preset(preset).diagnosis
    return [
        f"{preset}: [diagnosis] {key} = {committed.get(key)} in the file, fitted {fitted[key]:.4g}"
        for key in KEYS
        if key in fitted and committed.get(key) != float(f"{fitted[key]:.4g}")
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("presets", nargs="*", default=["cybership2", "supply"])
    ap.add_argument("--campaign", default="sweeps")
    ap.add_argument("--seeds", type=int, nargs="+", default=None,
                    help="calibration seeds (default: the campaign's tuning_seeds)")  # fmt: skip
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--check", action="store_true",
                    help="exit 1 where a preset file holds other values than the fit")  # fmt: skip
    args = ap.parse_args()
    wrong: list[str] = []
    for preset in args.presets:
        f = calibrate(preset, args.seeds, args.duration, args.campaign, args.workers)
        seeds = args.seeds or list(load_campaign(args.campaign).tuning_seeds)
        print(f"# {preset}: bench/calibrate_shaft.py {preset} --campaign {args.campaign} "
              f"--seeds {' '.join(map(str, seeds))} --duration {args.duration:g}: "
              f"{f['runs']} healthy runs, {f['hours']:.2f} h; "
              f"largest healthy CUSUM {f['peak']:.1f} (speed), "
              f"{f['load_peak']:.1f} (load); largest healthy loss shown "
              f"{100.0 * f['loss']:.1f} %")  # fmt: skip
        print("[diagnosis]")
        for key in KEYS:
            if key in f:  # the servos' bands only where the preset has servos
                print(f"{key} = {f[key]:.4g}")
        print()
        if not (math.isfinite(f["peak"]) and math.isfinite(f["load_peak"])):
            raise SystemExit(f"preset {preset}: a healthy CUSUM diverged")
        wrong += differences(preset, f) if args.check else []
    if wrong:
        raise SystemExit("the committed values are not what the calibration prints:\n"
                         + "\n".join(wrong))  # fmt: skip


if __name__ == "__main__":
    main()
