"""Benchmark: the live loop against offline, per realistic preset and fault case (issue 33).

Each case is the preset's shipped station-keeping scenario with its fault replaced (one
thruster, a cause, an onset) and its run shortened, flown live by ``ftcap-hil demo
--scenario`` (CAN hub, vessel on the realistic truth, allocator told the scenario, ground
station; real time unless ``--speed``) and offline (``run_mode``, the same seed), judged by
``report/hil_compare.py`` on the vessel's clock: deviation RMS from the offline fault-free
run, detection and isolation delays, false alarms. Also per flight: the allocator's cycles
and overruns (its "stopped after" line) and the largest command age the vessel saw (the
ESC stream's worst gap, from its record's ``command_age_s``).

    python bench/hil_cases.py [--preset cybership2|supply ...] [--speed K] [--out DIR]

Prints a markdown table (docs/hil.md). A flight takes the scenario's length in wall time
plus about 10 s of start-up; both presets' 12 cases about 17 minutes at real time.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ftcap_hil.config.scenario import SHIPPED, load_scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.report.hil_compare import (
    CaseMetrics,
    live_metrics,
    offline_metrics,
    read_columns,
)
from ftcap_hil.runtime.offline import run_mode

SCENARIOS = Path(__file__).resolve().parents[1] / SHIPPED.replace(".", "/")
STOP_LINE = re.compile(r"stopped after (\d+) cycles, (\d+) overruns")


@dataclass(frozen=True)
class Preset:
    scenario: str  # the shipped file
    shipped_fault: str  # its [[fault]] table's text, replaced by the case's
    duration_s: float
    onset_s: float
    main: int  # 1-based: the thruster the cases break
    label: str


PRESETS = {
    "cybership2": Preset(
        "cybership2-station", "[[fault]]\nfrom = 60.0\nthruster = 2\ndelta = 0.0\n",
        45.0, 20.0, 2, "starboard propeller",
    ),
    "supply": Preset(
        "supply-station-drawn", "[[fault]]\nfrom = 300.0\nthruster = 6\ndelta = 0.0\n",
        90.0, 40.0, 6, "port main",
    ),
}  # fmt: skip

# (name, the [[fault]] table's lines after from/thruster)
CASES = (
    ("drive dead", 'delta = 0.0\ncause = "drive-dead"'),
    ("jammed", 'delta = 0.0\ncause = "jammed"'),
    ("stuck", 'kind = "stuck"'),
    ("weak motor 0.5", 'delta = 0.5\ncause = "weak-motor"'),
    ("power lost (silent)", 'delta = 0.0\ncause = "power-lost"'),
    ("fouled 0.6", 'delta = 0.6\ncause = "fouled"'),
)


def case_file(folder: Path, preset: Preset, name: str, body: str) -> Path:
    text = (SCENARIOS / f"{preset.scenario}.toml").read_text()
    assert preset.shipped_fault in text, preset.scenario
    text = re.sub(r"(?m)^duration = [0-9.]+$", f"duration = {preset.duration_s}", text, count=1)
    fault = f"[[fault]]\nfrom = {preset.onset_s}\nthruster = {preset.main}\n{body}\n"
    path = folder / f"{preset.scenario}-{re.sub(r'[^a-z0-9]+', '-', name)}.toml"
    path.write_text(text.replace(preset.shipped_fault, fault))
    return path


@dataclass(frozen=True)
class Row:
    preset: str
    case: str
    live: CaseMetrics | None
    offline: CaseMetrics
    cycles: int
    overruns: int
    worst_gap_s: float
    wall_s: float
    error: str = ""


def fly(scenario: Path, out: Path, speed: float, duration_s: float) -> tuple[int, float, str]:
    cmd = [sys.executable, "-m", "ftcap_hil", "demo", "--scenario", str(scenario)]
    cmd += ["--speed", repr(speed), "--out", str(out), "--no-plots"]
    t0 = time.monotonic()
    proc = subprocess.run(
        cmd, capture_output=True, text=True, timeout=duration_s / speed + 300, check=False
    )
    return proc.returncode, time.monotonic() - t0, proc.stderr[-2000:]


def run_case(preset_name: str, case: str, body: str, folder: Path, speed: float) -> Row:
    preset = PRESETS[preset_name]
    path = case_file(folder, preset, case, body)
    sc = load_scenario(path)
    none, ftcap = run_mode(sc, Mode.NONE), run_mode(sc, Mode.FTCAP)
    offline = offline_metrics(ftcap, none)
    out = folder / path.stem
    code, wall, err = fly(path, out, speed, sc.duration_s)
    log = out / "logs" / "allocator.log"
    stop = STOP_LINE.search(log.read_text()) if log.exists() else None
    cycles, overruns = (int(stop.group(1)), int(stop.group(2))) if stop else (0, 0)
    vessel, gcs = out / "vessel.csv", out / "ftcap" / "timeseries.csv"
    if code != 0 or not (vessel.exists() and gcs.exists()):
        last = err.strip().splitlines()[-1] if err.strip() else ""
        return Row(preset_name, case, None, offline, cycles, overruns, np.nan, wall,
                   f"exit {code}: {last}")  # fmt: skip
    live = live_metrics(sc.faults, vessel, gcs, none)
    age = read_columns(vessel, ["time_s", "command_age_s"])
    settled = age["time_s"] > 2.0  # the first command arrives after the release
    gap = float(np.max(age["command_age_s"][settled])) if settled.any() else np.nan
    return Row(preset_name, case, live, offline, cycles, overruns, gap, wall)


def _s(x: float | None) -> str:
    return "never" if x is None else f"{x:.1f}"


def table(rows: list[Row], speed: float) -> str:
    lines = [
        f"| preset | case (at x{speed:g}) | deviation RMS live / offline (mm) | detection live / "
        "offline (s) | isolation live / offline (s) | false alarms live / offline | cycles "
        "(overruns) | worst command age (ms) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        off = r.offline
        if r.live is None:
            lines.append(f"| {r.preset} | {r.case} | failed: {r.error} | | | | | |")
            continue
        lv = r.live
        lines.append(
            f"| {r.preset} | {r.case} | {lv.deviation_rms_m * 1e3:.1f} / "
            f"{off.deviation_rms_m * 1e3:.1f} | {_s(lv.detection_s)} / {_s(off.detection_s)} | "
            f"{_s(lv.isolation_s)} / {_s(off.isolation_s)} | {lv.false_alarms} / "
            f"{off.false_alarms} | {r.cycles} ({r.overruns}) | {r.worst_gap_s * 1e3:.0f} |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", nargs="+", choices=sorted(PRESETS), default=sorted(PRESETS))
    ap.add_argument("--speed", type=float, default=1.0)
    ap.add_argument("--out", type=Path, default=None, help="keep the flights here")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.out or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for preset in args.preset:
            for case, body in CASES:
                row = run_case(preset, case, body, folder, args.speed)
                print(f"{preset} {case}: live {row.live}, offline {row.offline} "
                      f"({row.wall_s:.0f} s)", file=sys.stderr, flush=True)  # fmt: skip
                rows.append(row)
    print(table(rows, args.speed))


if __name__ == "__main__":
    main()
