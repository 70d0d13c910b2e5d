"""Text summaries of a ``results.json`` for the terminal."""

from __future__ import annotations

import math
from typing import Any


def offline_summary_lines(res: dict[str, Any]) -> list[str]:
    lines = [f"{res['scenario']}: phases {[(round(a, 2), round(b, 2)) for a, b in res['phases']]}"]
    for mode, r in res["modes"].items():
        phases = " | ".join(
            f"dev {p.get('deviation_rms', math.nan):.4f}/{p.get('deviation_max', math.nan):.3f}"
            f" trk {p['tracking_rms']:.3f}"
            for p in r["phases"]
        )
        lines.append(f"  {mode:14s} {phases}  cycle {r['cycle_us_median']:.0f} us")
    return lines


def flight_summary_lines(res: dict[str, Any]) -> list[str]:
    """Text summary of a results.json: per mode, per fault phase."""
    lines = [f"{res['scenario']}: {len(res['phases'])} phases"]
    for mode, r in res["modes"].items():
        lines.append(
            f"  mode {mode}: bounded {r['bounded']}, {r.get('cycles', '?')} cycles, "
            f"{r.get('overruns', '?')} overruns"
        )
        for p in r["phases"]:
            dh = " ".join(
                "-" if e is None or not math.isfinite(e) else f"{e:.3f}"
                for e in p["delta_error_final"]
            )
            lines.append(
                f"    [{p['start']:6.1f}, {p['end']:6.1f}) s  tracking rms {p['tracking_rms']:.3f}"
                f" max {p['tracking_max']:.3f} m  heading rms {p.get('heading_rms', math.nan):.3f}"
                f" rad  |delta_hat - delta| at end {dh}"
            )
    return lines
