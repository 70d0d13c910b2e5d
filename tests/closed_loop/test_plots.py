"""write_plots: the expected PNG files are written and contain real images."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.report.plots import write_plots
from ftcap_hil.runtime.offline import run_modes

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MODES = [Mode.NONE, Mode.CAP, Mode.FTCAP]
COMMON = [
    "virtual_inputs.png",
    "positions.png",
    "physical_inputs.png",
    "effectiveness.png",
    "bias.png",
]


def _check_png(path: Path) -> None:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE, path
    assert len(data) > 20_000, f"{path}: only {len(data)} bytes"
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 300 and img.shape[1] > 300
    flat = img[..., :3].reshape(-1, 3)
    assert np.ptp(flat, axis=0).max() > 0.5, f"{path}: (nearly) a single colour"
    assert len(np.unique(flat, axis=0)) > 20, f"{path}: too few colours"


@pytest.mark.parametrize(
    ("name", "duration", "expected"),
    [
        ("paper-4.1", None, COMMON),
        ("paper-4.2-ex2-bias008", 40.0, [*COMMON, "xy_path.png"]),
        # a Fossen 3-DOF truth model: the replay command a campaign prints once crashed here
        ("cybership2-station", 10.0, [*COMMON, "xy_path.png"]),
    ],
)
def test_write_plots(
    tmp_path: Path,
    name: str,
    duration: float | None,
    expected: list[str],
) -> None:
    sc = load_scenario(name)
    if duration is not None:
        sc = replace(sc, duration_s=duration)
    records = run_modes(sc, MODES)
    paths = write_plots(records, tmp_path / "plots")
    assert sorted(p.name for p in paths) == sorted(expected)
    assert sorted(p.name for p in (tmp_path / "plots").iterdir()) == sorted(expected)
    for p in paths:
        _check_png(p)


def test_write_plots_empty(tmp_path: Path) -> None:
    assert write_plots({}, tmp_path) == []
