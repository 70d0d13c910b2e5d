"""Distribution plots of a campaign (PNG): ECDFs per mode, box plots per fault kind.

``distributions.png``: empirical CDFs, one curve per mode, of the detection and isolation
delays (over detectable faults: a curve that stays below 1 shows the faults never
detected), of the delta-hat error after convergence, and of the deviation ratio to the
oracle. ``by_kind.png``: per fault kind and mode, box plots of the isolation delay and of
the deviation ratio to CAP. ``isolation_by_kind.png``: the isolation-delay ECDF per fault
kind, one curve per mode. ``dev_cap_by_scenario.png``: the deviation ratio to CAP per
scenario and mode. ``sweep_map.png``: per estimating mode, the share of detectable faults
isolated within 30 s per scenario (rows: the conditions of a sweep) and fault kind, each
cell annotated with the shares within 5 s / 30 s / never.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402

from ftcap_hil.report.plots import EXTRA_COLORS, MODE_COLORS  # noqa: E402

Row = dict[str, Any]
DPI = 100


def _color(mode: str, modes: list[str]) -> str:
    extra = [m for m in modes if m not in MODE_COLORS]
    return MODE_COLORS.get(mode) or EXTRA_COLORS[extra.index(mode) % len(EXTRA_COLORS)]


def _ecdf(ax: Axes, values: list[float | None], label: str, color: str) -> None:
    """Steps over the finite values; None / inf count in the total, so misses show."""
    if not values:
        return
    finite = np.sort([v for v in values if v is not None and np.isfinite(v)])
    y = np.arange(1, finite.size + 1) / len(values)
    ax.step(
        np.concatenate([[0.0], finite]),
        np.concatenate([[0.0], y]),
        where="post",
        label=f"{label} (n={len(values)})",
        color=color,
    )


def _modes(rows: list[Row]) -> list[str]:
    return list(dict.fromkeys(r["variant"] for r in rows if r["mode"] != "none"))


def _distributions(rows: list[Row], faults: list[Row], path: Path) -> None:
    fig, axes = plt.subplots(2, 2, figsize=(11.0, 8.0))
    modes = _modes(rows)
    panels = [
        (axes[0, 0], "detection delay (s)", faults, "detection_delay_s", "detectable"),
        (axes[0, 1], "isolation delay (s)", faults, "isolation_delay_s", "detectable"),
        (axes[1, 0], "|delta_hat - delta| after convergence", faults, "delta_error", None),
        (axes[1, 1], "deviation RMS / oracle's", rows, "dev_ratio_oracle", None),
    ]
    for ax, title, data, key, only in panels:
        for mode in modes:
            sel = [r for r in data if r["variant"] == mode and (only is None or r[only])]
            if key == "dev_ratio_oracle":
                sel = [r for r in sel if r.get(key) is not None]
            _ecdf(ax, [r.get(key) for r in sel], mode, _color(mode, modes))
        ax.set_title(title)
        ax.set_ylabel("fraction")
        ax.set_ylim(0.0, 1.02)
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def _boxes(ax: Axes, data: list[Row], key: str, modes: list[str], title: str) -> None:
    kinds = sorted({r["kind"] for r in data})
    width = 0.8 / max(len(modes), 1)
    for j, mode in enumerate(modes):
        series = [
            [
                r[key]
                for r in data
                if r["variant"] == mode
                and r["kind"] == k
                and r.get(key) is not None
                and np.isfinite(r[key])
            ]
            for k in kinds
        ]
        pos = [i + (j - (len(modes) - 1) / 2) * width for i in range(len(kinds))]
        keep = [(p, s) for p, s in zip(pos, series, strict=True) if s]
        if keep:
            bp = ax.boxplot(
                [s for _, s in keep],
                positions=[p for p, _ in keep],
                widths=width * 0.9,
                patch_artist=True,
                manage_ticks=False,
            )
            for patch in bp["boxes"]:
                patch.set_facecolor(_color(mode, modes))
            ax.plot([], [], color=_color(mode, modes), lw=6, label=mode)
    ax.set_xticks(range(len(kinds)), kinds)
    ax.set_title(title)
    ax.grid(alpha=0.3, axis="y")
    if modes:
        ax.legend(fontsize=8)


def _by_kind(rows: list[Row], faults: list[Row], path: Path) -> None:
    fig, axes = plt.subplots(2, 1, figsize=(11.0, 8.0))
    modes = [m for m in _modes(rows) if m != "cap"]
    detectable = [f for f in faults if f["detectable"]]
    _boxes(axes[0], detectable, "isolation_delay_s", modes, "isolation delay (s), when isolated")
    _boxes(
        axes[1],
        [r for r in rows if r["status"] == "ok"],
        "dev_ratio_cap",
        modes,
        "deviation RMS / CAP's",
    )
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def _isolation_by_kind(rows: list[Row], faults: list[Row], path: Path) -> None:
    detectable = [f for f in faults if f["detectable"]]
    kinds = sorted({f["kind"] for f in detectable}) or ["-"]
    modes = [m for m in _modes(rows) if m != "cap"]
    cols = min(3, len(kinds))
    nrows = math.ceil(len(kinds) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.0 * cols, 3.2 * nrows), squeeze=False)
    for ax, kind in zip(axes.flat, kinds, strict=False):
        for mode in modes:
            sel = [f for f in detectable if f["variant"] == mode and f["kind"] == kind]
            _ecdf(ax, [f["isolation_delay_s"] for f in sel], mode, _color(mode, modes))
        ax.set_title(f"{kind}: isolation delay (s)")
        ax.set_xscale("symlog", linthresh=1.0)
        ax.set_ylim(0.0, 1.02)
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    for ax in list(axes.flat)[len(kinds) :]:
        ax.set_visible(False)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def _dev_cap_by_scenario(rows: list[Row], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(11.0, 4.5))
    modes = [m for m in _modes(rows) if m != "cap"]
    ok = [{**r, "kind": r["scenario"]} for r in rows if r["status"] == "ok"]
    _boxes(ax, ok, "dev_ratio_cap", modes, "deviation RMS / CAP's, per scenario")
    ax.axhline(1.05, color="k", lw=0.8, ls="--")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def _sweep_map(sweep: list[Row], path: Path) -> None:
    cells = [r for r in sweep if r["kind"] != "healthy" and r["mode"] not in ("cap", "oracle")]
    modes = list(dict.fromkeys(r["mode"] for r in cells)) or ["-"]
    scenarios = list(dict.fromkeys(r["scenario"] for r in cells))
    kinds = sorted({r["kind"] for r in cells})
    fig, axes = plt.subplots(
        len(modes),
        1,
        figsize=(1.6 * max(len(kinds), 2) + 3.0, 0.6 * max(len(scenarios), 1) * len(modes) + 1.5),
        squeeze=False,
    )
    for ax, mode in zip(axes[:, 0], modes, strict=True):
        grid = np.full((len(scenarios), len(kinds)), np.nan)
        for r in cells:
            if r["mode"] == mode:
                i, j = scenarios.index(r["scenario"]), kinds.index(r["kind"])
                grid[i, j] = r["isolated_30s"]
                text = "/".join(
                    f"{100 * r[k]:.0f}" for k in ("isolated_5s", "isolated_30s", "never")
                )
                ax.text(j, i, f"{text}\n(n={r['faults']})", ha="center", va="center", fontsize=7)
        ax.imshow(grid, cmap="RdYlGn", vmin=0.0, vmax=1.0, aspect="auto")
        ax.set_xticks(range(len(kinds)), kinds)
        ax.set_yticks(range(len(scenarios)), scenarios)
        ax.set_title(f"{mode}: % isolated <= 5 s / <= 30 s / never (colour: <= 30 s)")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def write_campaign_plots(
    rows: list[Row], faults: list[Row], out_dir: Path, sweep: list[Row] | None = None
) -> list[Path]:
    """The PNGs of the module docstring in out_dir (``sweep``: the map's rows, from
    ``campaign_sweep.sweep_rows``; None: no map); returns their paths."""
    names = ["distributions", "by_kind", "isolation_by_kind", "dev_cap_by_scenario"]
    paths = [out_dir / f"{name}.png" for name in names]
    _distributions(rows, faults, paths[0])
    _by_kind(rows, faults, paths[1])
    _isolation_by_kind(rows, faults, paths[2])
    _dev_cap_by_scenario(rows, paths[3])
    if sweep is not None:
        paths.append(out_dir / "sweep_map.png")
        _sweep_map(sweep, paths[-1])
    return paths
