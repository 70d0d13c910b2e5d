"""Closed-loop runs of the shipped paper scenarios, with the targets of the core issue.

``ftcap`` runs the default (Kalman) estimator; the paper's own targets were set for the
windowed least squares, which is pinned to them here too (``kind="windowed"``). Where the
two differ the Kalman estimator trades noise-free speed for robustness to noise; its bounds
below are its measured figures with a margin, and tests/closed_loop/test_noise_targets.py
holds the targets it was built for.
"""

from __future__ import annotations

import dataclasses
import math
from functools import cache
from typing import Any

import numpy as np
import pytest

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.estimation.config import EstimatorKind
from ftcap_hil.core.models.plants import Inversion
from ftcap_hil.core.scenario import Integrator, Scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.report.records import results
from ftcap_hil.runtime.offline import run_modes

ALL = [Mode.NONE, Mode.CAP, Mode.FTCAP, Mode.FTCAP_LITERAL, Mode.ORACLE]


@cache
def _results(
    name: str,
    integrator: str | None = None,
    inversion: str | None = None,
    kind: str | None = None,
) -> tuple[Any, Any]:
    sc: Scenario = load_scenario(name)
    if kind:
        est = dataclasses.replace(sc.core.estimator, kind=EstimatorKind(kind))
        sc = dataclasses.replace(sc, core=dataclasses.replace(sc.core, estimator=est))
    if integrator:
        sc = dataclasses.replace(sc, integrator=Integrator(integrator))
    if inversion:
        plant = dataclasses.replace(sc.plant, inversion=Inversion(inversion))
        sc = dataclasses.replace(sc, plant=plant)
    recs = run_modes(sc, ALL)
    return results(recs), recs


def _phase(res: dict, mode: str, i: int) -> dict:  # type: ignore[type-arg]
    return res["modes"][mode]["phases"][i]


# --- section 4.1: linear unstable plant --------------------------------------------------


@pytest.mark.parametrize("phase", [1, 2])  # onsets at t = 12 and t = 201 steps
def test_linear_ftcap_recovers_tracking_and_identifies_faults(phase: int) -> None:
    res, _ = _results("paper-4.1")
    p = _phase(res, "ftcap", phase)
    assert p["settle_time"] is not None and p["settle_time"] <= 20, p
    conv = p["delta_convergence_time"]
    assert all(c is not None and c <= 25 for c in conv), conv


@pytest.mark.parametrize("phase", [1, 2])
def test_linear_cap_keeps_a_steady_offset(phase: int) -> None:
    res, recs = _results("paper-4.1")
    assert _phase(res, "cap", phase)["settle_time"] is None
    c = recs["cap"].columns
    t = recs["cap"].t
    end = res["phases"][phase][1]
    last = (t > end - 20) & (t < end)
    assert np.min(np.abs(c["x"][last] - c["ref_x"][last])) > 0.02


def test_linear_literal_estimator_never_leaves_identity() -> None:
    _, recs = _results("paper-4.1")
    c = recs["ftcap-literal"].columns
    for i in (1, 2, 3):
        assert np.all(c[f"delta_hat_{i}"] == 1.0)


# --- section 4.2, example 1 --------------------------------------------------------------


@pytest.mark.parametrize("phase", [1, 2])
def test_ex1_delta_hat_converges_within_30_s(phase: int) -> None:
    res, _ = _results("paper-4.2-ex1")
    conv = _phase(res, "ftcap", phase)["delta_convergence_time"]
    assert all(c is not None and c <= 30.0 for c in conv), conv


@pytest.mark.parametrize(
    ("kind", "phase", "factor"),
    [
        ("windowed", 0, 1.1),
        ("windowed", 1, 1.1),
        ("windowed", 2, 1.1),
        ("kalman", 0, 1.1),
        # The Kalman estimator waits for the sample after the one straddling the onset and
        # acts on thruster 1's 0.9 only as its variance allows: 0.0024 m against 0.0018 m
        # (measured; CAP 0.0236 m).
        ("kalman", 1, 1.5),
        ("kalman", 2, 1.1),
    ],
)
def test_ex1_deviation_near_the_oracle(kind: str, phase: int, factor: float) -> None:
    res, _ = _results("paper-4.2-ex1", kind=kind)
    ftcap = _phase(res, "ftcap", phase)["deviation_rms"]
    oracle = _phase(res, "oracle", phase)["deviation_rms"]
    assert ftcap <= factor * oracle + 1e-6, (ftcap, oracle)


def test_ex1_cap_measurably_worse() -> None:
    res, _ = _results("paper-4.2-ex1")
    # Phase 1 (thruster 1 at 90 % with a bias): CAP deviates ~10x more than F-TCAP.
    assert _phase(res, "cap", 1)["deviation_rms"] > 5 * _phase(res, "ftcap", 1)["deviation_rms"]
    # CAP never identifies anything: its delta_hat stays 1 against a truth of 0.9 / 0.
    assert _phase(res, "cap", 1)["delta_convergence_time"][0] is None
    assert _phase(res, "cap", 2)["delta_convergence_time"][2] is None
    for mode in ("cap", "ftcap", "oracle"):
        assert res["modes"][mode]["bounded"]
        assert res["modes"][mode]["fallback_cycles"] == 0


@pytest.mark.parametrize(("kind", "factor"), [("windowed", 1.1), ("kalman", 3.0)])
def test_ex1_rk4_truth_with_trapezoid_inversion_still_converges(kind: str, factor: float) -> None:
    """A finer truth than the model: phase 1 of the Kalman estimator is 0.00135 m against
    the oracle's 0.00049 m (measured), both 20x below CAP's."""
    res, _ = _results("paper-4.2-ex1", integrator="rk4", inversion="trapezoid", kind=kind)
    for phase in (1, 2):
        conv = _phase(res, "ftcap", phase)["delta_convergence_time"]
        assert all(c is not None and c <= 30.0 for c in conv), conv
        ftcap = _phase(res, "ftcap", phase)["deviation_rms"]
        bound = factor if phase == 1 else 1.1
        assert ftcap <= bound * _phase(res, "oracle", phase)["deviation_rms"] + 1e-6


# --- section 4.2, example 2 --------------------------------------------------------------


def test_ex2_as_printed_no_allocator_holds_position() -> None:
    """A 0.8 N bias against three thrusters limited to 0.1 N: physically impossible."""
    res, _ = _results("paper-4.2-ex2")
    for mode in ("cap", "ftcap", "oracle"):
        assert _phase(res, mode, 1)["tracking_max"] > 1.0, mode


def test_ex2_bias008_ftcap_holds_position_cap_drifts() -> None:
    res, _ = _results("paper-4.2-ex2-bias008")
    assert _phase(res, "ftcap", 1)["tracking_max"] < 0.1
    assert _phase(res, "cap", 1)["tracking_max"] > 0.3
    assert _phase(res, "ftcap", 2)["tracking_max"] < 0.1  # the fault clears at 200 s


def test_ex2_bias008_dead_thruster_recovers_through_probes() -> None:
    """Thruster 2 is dead from 12 s to 200 s; F-TCAP stops using it, then must notice that
    it works again, although it commands nothing to it but the recovery probes."""
    res, recs = _results("paper-4.2-ex2-bias008")
    c, t = recs["ftcap"].columns, recs["ftcap"].t
    dead = (t > 20) & (t < 200)
    assert np.all(c["delta_hat_2"][dead] < 0.05)
    idle = dead & (c["probing"] == 0)
    assert np.all(c["u_2"][idle] == 0.0)  # no command outside the probe windows
    conv = _phase(res, "ftcap", 2)["delta_convergence_time"][1]
    assert conv is not None and conv <= 30.0


@pytest.mark.parametrize(("kind", "bound"), [("windowed", 0.6), ("kalman", 0.75)])
def test_ex2_limits10_ftcap_holds_position_cap_drifts(kind: str, bound: float) -> None:
    res, _ = _results("paper-4.2-ex2-limits10", kind=kind)
    # A 0.8 N bias is seen one sample late, and the sample straddling the onset is only
    # used until a clean one arrives: ~0.54 m under the paper's gains (windowed; the Kalman
    # estimator waits one sample more: 0.67 m); CAP drifts by metres.
    assert _phase(res, "ftcap", 1)["tracking_max"] < bound
    assert _phase(res, "cap", 1)["tracking_max"] > 3.0
    assert math.isfinite(_phase(res, "ftcap", 1)["deviation_rms"])


# --- measurement noise (docs/algorithm.md, known limitation) ------------------------------


def _noisy_ex1(std: float, seed: int, **estimator: float | EstimatorKind) -> tuple[Any, Any]:
    sc = load_scenario("paper-4.2-ex1")
    noise = np.array([std if s in ("u", "v", "r") else 0.0 for s in sc.plant.state_labels])
    core = dataclasses.replace(
        sc.core, estimator=dataclasses.replace(sc.core.estimator, **estimator)
    )
    sc = dataclasses.replace(sc, noise_std=noise, seed=seed, core=core, duration_s=60.0)
    return results(run_modes(sc, [Mode.NONE, Mode.CAP, Mode.FTCAP]))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_velocity_noise_kalman_does_no_harm_and_beats_cap(seed: int) -> None:
    """1e-3 m/s of velocity noise (as large, on this 1.1 kg vessel, as a thruster's range):
    before the fault the Kalman estimator leaves the allocation exactly CAP's (deviation
    ~1e-17 m, measured), while the windowed estimator's noisy estimates already move it
    (~1e-3 m); after the onset it compensates the attributed 0.01 N bias (0.012 m against
    CAP's 0.026 m, measured over seeds 0-3)."""
    kalman = _noisy_ex1(1e-3, seed)
    windowed = _noisy_ex1(1e-3, seed, kind=EstimatorKind.WINDOWED)
    assert _phase(kalman, "ftcap", 0)["deviation_rms"] < 1e-9
    assert _phase(windowed, "ftcap", 0)["deviation_rms"] > 1e-4
    cap = _phase(kalman, "cap", 1)["deviation_rms"]
    assert _phase(kalman, "ftcap", 1)["deviation_rms"] < cap / 1.5


def test_prefilter_keeps_noise_free_onset_reaction() -> None:
    """The prefilter restarts with the window and again after the straddling sample is
    evicted: noise-free, ex2-bias008 converges as fast as unfiltered (1.0 s, measured; 6 s
    when the filter kept the straddling sample's memory)."""
    sc = load_scenario("paper-4.2-ex2-bias008")
    core = dataclasses.replace(
        sc.core,
        estimator=dataclasses.replace(
            sc.core.estimator, kind=EstimatorKind.WINDOWED, prefilter=0.3
        ),
    )
    res = results(run_modes(dataclasses.replace(sc, core=core, duration_s=60.0), [Mode.FTCAP]))
    conv = _phase(res, "ftcap", 1)["delta_convergence_time"]
    assert all(c is not None and c <= 1.5 for c in conv), conv
