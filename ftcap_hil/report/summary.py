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
            dh = " ".join(_num(e) for e in p["delta_error_final"])
            lines.append(
                f"    [{p['start']:6.1f}, {p['end']:6.1f}) s"
                f"  tracking rms {_num(p['tracking_rms'])} max {_num(p['tracking_max'])} m"
                f"  heading rms {_num(p.get('heading_rms'))} rad"
                f"  |delta_hat - delta| at end {dh}"
            )
    return lines


def _num(x: float | None) -> str:
    """A metric as written in results.json (None: never / not measured) -> '-' or 0.123."""
    return "-" if x is None or not math.isfinite(x) else f"{x:.3f}"
