"""Issue 15's target on the paper's vessel: velocity noise 1e-3 (white, on u, v, r), one
thruster dead while station keeping (``paper-4.2-station-dead``): in every one of 20 seeds
the dead thruster is taken out within 5 s and no healthy thruster's delta-hat goes below
0.85 at any time. Measured: out after 2.6-3.4 s (median 2.9 s); healthy minimum 0.870."""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.offline import run_mode

ONSET_S = 50.0
DEAD = 2  # thruster 3


@cache
def _run(seed: int) -> tuple[float, float, float]:
    """(seconds until taken out, lowest healthy delta-hat, pre-fault deviation from CAP)."""
    sc = dataclasses.replace(load_scenario("paper-4.2-station-dead"), seed=seed)
    rec = run_mode(sc, Mode.FTCAP)
    c, t = rec.columns, rec.t
    # Taken out: from then on it gets nothing but the recovery probes.
    quiet = (np.abs(c[f"u_{DEAD + 1}"]) < 1e-12) | (c["probing"] > 0)
    after = np.flatnonzero(t >= ONSET_S)
    out = next((t[j] - ONSET_S for j in after if quiet[j:].all()), np.inf)
    healthy = np.column_stack([c[f"delta_hat_{i + 1}"] for i in range(4) if i != DEAD])
    cap = run_mode(sc, Mode.CAP).columns
    before = t < ONSET_S
    dev = np.hypot(c["north"] - cap["north"], c["east"] - cap["east"])[before].max()
    return float(out), float(healthy.min()), float(dev)


@pytest.mark.parametrize("seed", range(20))
def test_dead_thruster_out_within_5_s_and_healthy_ones_stay_above_0_85(seed: int) -> None:
    out, healthy_min, _ = _run(seed)
    assert out <= 5.0, out
    assert healthy_min >= 0.85, healthy_min


@pytest.mark.parametrize("seed", range(3))
def test_before_the_fault_the_excitation_costs_little_position(seed: int) -> None:
    """The noise-sized dither lives in the null space: before the fault F-TCAP holds the
    same position as CAP to within 5 mm (1.7 % of this 0.3 m vessel)."""
    assert _run(seed)[2] < 0.005
