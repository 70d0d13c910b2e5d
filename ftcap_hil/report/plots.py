"""PNG figures of a set of runs on one scenario, the modes overlaid (like the paper's figures).

``write_plots(records, out_dir)`` takes ``run_modes`` output (mode name -> RunRecord) and
writes ``virtual_inputs.png``, ``positions.png``, ``xy_path.png`` (vessel only),
``physical_inputs.png``, ``effectiveness.png`` and ``bias.png``. Each mode has a fixed
colour; the fault-free ``none`` run is grey and dashed. Fault changes are dotted lines.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from ftcap_hil.core.messages import FloatArray  # noqa: E402
from ftcap_hil.core.models.plants import LinearPlant  # noqa: E402
from ftcap_hil.core.scenario import Scenario, TimeUnit
from ftcap_hil.report.records import RunRecord  # noqa: E402

FIGSIZE = (10.0, 7.0)
DPI = 100
MODE_COLORS = {
    "none": "0.55",
    "cap": "tab:red",
    "ftcap": "tab:blue",
    "ftcap-literal": "tab:orange",
    "oracle": "tab:green",
}
EXTRA_COLORS = ("tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan")
TRUTH: dict[str, Any] = {"color": "black", "lw": 2.4, "alpha": 0.7, "zorder": 1}
VESSEL_V = ("surge X", "sway Y", "yaw N")
VESSEL_V_UNITS = ("N", "N", "N m")

Records = dict[str, RunRecord]


def _style(mode: str, modes: list[str]) -> dict[str, Any]:
    if mode == "none":
        return {"color": MODE_COLORS["none"], "ls": "--", "lw": 1.2, "zorder": 2, "label": mode}
    extra = [m for m in modes if m not in MODE_COLORS]
    color = MODE_COLORS.get(mode) or EXTRA_COLORS[extra.index(mode) % len(EXTRA_COLORS)]
    return {"color": color, "ls": "-", "lw": 1.3, "zorder": 3, "label": mode}


def _scenario(records: Records) -> Scenario:
    return next(iter(records.values())).scenario


def _is_vessel(sc: Scenario) -> bool:
    return not isinstance(sc.plant, LinearPlant)  # every other plant has a pose (records.py)


def _v_label(sc: Scenario, j: int, prefix: str = "") -> str:
    if _is_vessel(sc) and j < len(VESSEL_V):
        return f"{prefix}{VESSEL_V[j]} [{VESSEL_V_UNITS[j]}]"
    return f"{prefix}v_{j + 1} [-]"


def _faulty(records: Records) -> list[tuple[str, RunRecord]]:
    """Runs with faults injected: everything but the fault-free ``none`` reference."""
    return [(n, r) for n, r in records.items() if n != "none"]


def _truth_record(records: Records) -> RunRecord:
    faulty = _faulty(records)
    return faulty[0][1] if faulty else next(iter(records.values()))


def _time_label(sc: Scenario) -> str:
    return "time [step]" if sc.time_unit is TimeUnit.STEP else "time [s]"


def _fault_lines(ax: Axes, sc: Scenario) -> None:
    for start, _ in sc.phases()[1:]:
        ax.axvline(start, color="black", ls=":", lw=1.0, zorder=0)


def _grid(sc: Scenario, n: int, title: str, ncols: int = 1) -> tuple[Figure, list[Axes]]:
    nrows = -(-n // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=FIGSIZE, dpi=DPI, sharex=True, squeeze=False)
    flat = list(axes.ravel())
    for ax in flat[n:]:
        ax.set_visible(False)
    for ax in flat[:n]:
        ax.grid(True, alpha=0.3)
        _fault_lines(ax, sc)
    for ax in flat[max(0, n - ncols) : n]:
        ax.set_xlabel(_time_label(sc))
    fig.suptitle(f"{sc.name}: {title}")
    return fig, flat[:n]


def _save(fig: Figure, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def _overlay(
    axes: list[Axes],
    records: Records,
    key: Callable[[int], str],
    runs: list[tuple[str, RunRecord]] | None = None,
    **kw: Any,
) -> None:
    """For each axis i, plot column ``key(i)`` of every run in ``runs`` (default: all)."""
    modes = list(records)
    for name, rec in runs if runs is not None else list(records.items()):
        style = {**_style(name, modes), **kw}
        for i, ax in enumerate(axes):
            ax.plot(rec.t, rec.columns[key(i)], **style)


def _legend(ax: Axes, **kw: Any) -> None:
    ax.legend(loc="best", fontsize="small", framealpha=0.8, **kw)


def plot_virtual_inputs(records: Records, path: Path) -> Path:
    sc = _scenario(records)
    k = sc.B.shape[0]
    fig, axes = _grid(sc, k, "demanded (thick) and achieved (thin) virtual inputs")
    _overlay(axes, records, lambda j: f"v_dem_{j + 1}")
    _overlay(axes, records, lambda j: f"v_ach_{j + 1}", lw=0.6, alpha=0.8, label=None)
    for j, ax in enumerate(axes):
        ax.set_ylabel(_v_label(sc, j))
    _legend(axes[0])
    return _save(fig, path)


def plot_positions(records: Records, path: Path) -> Path:
    sc = _scenario(records)
    ref = _truth_record(records)
    if not _is_vessel(sc):
        fig, axes = _grid(sc, 1, "state x and reference r")
        axes[0].plot(ref.t, ref.columns["ref_x"], label="r", **TRUTH)
        _overlay(axes, records, lambda _: "x")
        axes[0].set_ylabel("x [-]")
        _legend(axes[0])
        return _save(fig, path)
    fig, axes = _grid(sc, 3, "pose and reference")
    labels = ("north [m]", "east [m]", "psi [rad]")
    for ax, state, label in zip(axes, ("north", "east", "psi"), labels, strict=True):
        ax.plot(ref.t, ref.columns[f"ref_{state}"], label="reference", **TRUTH)
        ax.set_ylabel(label)
    _overlay(axes, records, lambda i: ("north", "east", "psi")[i])
    _legend(axes[0])
    return _save(fig, path)


def plot_xy_path(records: Records, path: Path) -> Path:
    sc = _scenario(records)
    fig, ax = plt.subplots(figsize=FIGSIZE, dpi=DPI)
    modes = list(records)
    for name, rec in records.items():
        ax.plot(rec.columns["east"], rec.columns["north"], **_style(name, modes))
    way = np.array([seg.value[:2] for seg in sc.reference])
    ax.plot(way[:, 1], way[:, 0], "kx", ms=10, mew=2, label="reference waypoints", zorder=4)
    labels: dict[tuple[float, float], list[str]] = {}
    for i, (north, east) in enumerate(way):
        labels.setdefault((float(north), float(east)), []).append(str(i + 1))
    for (north, east), idx in labels.items():
        ax.annotate(",".join(idx), (east, north), textcoords="offset points", xytext=(6, 6))
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.set_title(f"{sc.name}: path in the horizontal plane (NED)")
    _legend(ax)
    return _save(fig, path)


def _limit_lines(ax: Axes, lo: float, hi: float) -> None:
    """Amplitude limits as lines; a limit far outside the data (more than one data span
    away) would flatten the curves, so it is only written in the corner."""
    d_lo, d_hi = ax.get_ylim()
    span = d_hi - d_lo
    shown = [v for v in (lo, hi) if d_lo - span <= v <= d_hi + span]
    for v in shown:
        ax.axhline(v, color="black", ls="-.", lw=0.9, zorder=1)
    if len(shown) < 2:
        ax.text(
            0.01,
            0.04,
            f"limits [{lo:g}, {hi:g}]",
            transform=ax.transAxes,
            fontsize="small",
            bbox={"fc": "white", "ec": "none", "alpha": 0.8},
        )


def plot_physical_inputs(records: Records, path: Path) -> Path:
    sc = _scenario(records)
    ths = sc.thrusters
    unit = "N" if _is_vessel(sc) else "-"
    title = "produced thrust tau_i = delta_i u_i + f_i"
    fig, axes = _grid(sc, ths.m, title, ncols=2 if ths.m > 3 else 1)
    _overlay(axes, records, lambda i: f"tau_{i + 1}")
    for i, ax in enumerate(axes):
        _limit_lines(ax, ths.u_min[i], ths.u_max[i])
        ax.set_ylabel(f"tau_{i + 1} ({ths.names[i]}) [{unit}]")
    _legend(axes[0])
    return _save(fig, path)


def plot_effectiveness(records: Records, path: Path) -> Path:
    sc = _scenario(records)
    m = sc.thrusters.m
    fig, axes = _grid(sc, m, "effectiveness estimate delta_hat_i vs truth", ncols=2 if m > 3 else 1)
    truth = _truth_record(records)
    for i, ax in enumerate(axes):
        ax.plot(truth.t, truth.columns[f"delta_{i + 1}"], label="truth", **TRUTH)
        ax.set_ylim(-0.05, 1.05)
        ax.set_ylabel(f"delta_{i + 1} [-]")
    _overlay(axes, records, lambda i: f"delta_hat_{i + 1}", runs=_faulty(records))
    _legend(axes[0])
    return _save(fig, path)


def _bf_truth(rec: RunRecord) -> FloatArray:
    sc = rec.scenario
    f = np.column_stack([rec.columns[f"f_{i + 1}"] for i in range(sc.thrusters.m)])
    return f @ sc.B.T


def plot_bias(records: Records, path: Path) -> Path:
    sc = _scenario(records)
    m, k = sc.thrusters.m, sc.B.shape[0]
    ncols = max(m, k)
    fig, axes = _grid(sc, 2 * ncols, "bias estimates: f_hat_i (top), B f_hat (bottom)", ncols=ncols)
    top, bottom = axes[:m], axes[ncols : ncols + k]
    for ax in axes[m:ncols] + axes[ncols + k :]:
        ax.set_visible(False)
    for ax in top[k:]:  # nothing below them: show their time axis
        ax.xaxis.set_tick_params(labelbottom=True)
        ax.set_xlabel(_time_label(sc))
    truth = _truth_record(records)
    bf = _bf_truth(truth)
    unit = "N" if _is_vessel(sc) else "-"
    for i, ax in enumerate(top):
        ax.plot(truth.t, truth.columns[f"f_{i + 1}"], label="truth", **TRUTH)
        ax.set_ylabel(f"f_{i + 1} [{unit}]")
    for j, ax in enumerate(bottom):
        ax.plot(truth.t, bf[:, j], label="truth", **TRUTH)
        ax.set_ylabel(_v_label(sc, j, "(B f) "))
    runs = _faulty(records)
    _overlay(top, records, lambda i: f"f_hat_{i + 1}", runs=runs)
    _overlay(bottom, records, lambda j: f"bf_hat_{j + 1}", runs=runs)
    _legend(top[0])
    return _save(fig, path)


def write_plots(records: Records, out_dir: Path) -> list[Path]:
    """Write the figures for runs of one scenario into ``out_dir``; return their paths."""
    if not records:
        return []
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    plots: list[tuple[str, Callable[[Records, Path], Path]]] = [
        ("virtual_inputs.png", plot_virtual_inputs),
        ("positions.png", plot_positions),
        ("physical_inputs.png", plot_physical_inputs),
        ("effectiveness.png", plot_effectiveness),
        ("bias.png", plot_bias),
    ]
    if _is_vessel(_scenario(records)):
        plots.insert(2, ("xy_path.png", plot_xy_path))
    return [fn(records, out_dir / name) for name, fn in plots]
