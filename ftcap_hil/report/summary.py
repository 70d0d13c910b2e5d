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


# A fault phase is handled when every thruster's estimate ended within this of the truth ...
VERDICT_DELTA_TOL = 0.1
# ... and the HIL run tracked its reference no worse than this multiple of the offline F-TCAP
# run of the same scenario, plus VERDICT_TRACK_SLACK_M (transport delay and jitter: the
# offline run acts on each sample at once).
VERDICT_TRACK_RATIO = 2.0
VERDICT_TRACK_SLACK_M = 0.05


def verdict_lines(flight: dict[str, Any], offline: dict[str, Any]) -> tuple[list[str], bool]:
    """Per fault phase of a HIL flight (its results.json): what was injected, when the
    estimate got there, its error at the phase end, and the tracking against what the offline
    simulator expects of F-TCAP and of CAP on the same scenario (``offline``: results of
    ``none``, ``cap`` and ``ftcap``); then a plain verdict. Returns (lines, all handled)."""
    mode, run = next(iter(flight["modes"].items()))
    exp = offline["modes"]
    injections = run.get("injections", [])
    lines, handled_all = [f"verdict ({mode} over MAVLink/CAN against the offline simulator):"], True
    for i, p in enumerate(run["phases"]):
        start, end = p["start"], p["end"]
        sent = [j for j in injections if start - 1.0 <= (j.get("sent_at_s") or j["at_s"]) < end]
        if i == 0 and not sent:
            what = "no fault"
        else:
            what = (
                ", ".join(
                    f"{j['kind']} thruster {j['thruster']}"
                    + ("" if j.get("value") is None else f" ({j['value']:g})")
                    + ("" if j["result"] == "ACCEPTED" else f" [{j['result']}]")
                    for j in sent
                )
                or "faults as before"
            )
        errors = [e for e in p["delta_error_final"] if e is not None]
        conv = [c for c in p.get("delta_convergence_time", []) if c is not None]
        never = [n + 1 for n, c in enumerate(p.get("delta_convergence_time", [])) if c is None]
        ftcap = exp["ftcap"]["phases"][i]["tracking_rms"] if "ftcap" in exp else None
        cap = exp["cap"]["phases"][i]["tracking_rms"] if "cap" in exp else None
        worst = max(errors, default=math.nan)
        track_ok = ftcap is None or (
            p["tracking_rms"] is not None
            and p["tracking_rms"] <= VERDICT_TRACK_RATIO * ftcap + VERDICT_TRACK_SLACK_M
        )
        ok = not never and worst <= VERDICT_DELTA_TOL and track_ok
        handled_all &= ok
        est = (
            f"estimate never within {VERDICT_DELTA_TOL} for thruster {never}"
            if never
            else f"estimates within {VERDICT_DELTA_TOL} after {max(conv, default=0.0):.1f} s"
            if max(conv, default=0.0) > 0.0
            else f"estimates within {VERDICT_DELTA_TOL} throughout"
        )
        lines.append(
            f"  [{start:6.1f}, {end:6.1f}) s  {what}: {est}, worst error at end {_num(worst)};"
            f" tracking rms {_num(p['tracking_rms'])} m (offline F-TCAP {_num(ftcap)},"
            f" CAP {_num(cap)}) -> {'handled' if ok else 'NOT handled'}"
        )
    n = len(run["phases"])
    lines.append(
        "VERDICT: every fault phase handled"
        if handled_all
        else f"VERDICT: not every fault handled ({n} phases; see above and the logs)"
    )
    return lines, handled_all
