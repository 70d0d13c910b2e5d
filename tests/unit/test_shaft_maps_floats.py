"""The drives' speed and load maps learn in floats (issue 31): the algebra held to its numpy
reference, sample by sample and over whole runs."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.estimation import shaft_channel
from ftcap_hil.core.estimation.shaft_channel import (
    LoadModel,
    SpeedMap,
    kalman3,
    kalman3_reference,
)
from ftcap_hil.core.estimation.shaft_types import (
    HYPOTHESIS_CODES,
    DiagnosisConfig,
    DriveModel,
    Hypothesis,
)
from ftcap_hil.core.faults import Cause
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.offline import run_mode


def _random_covariance(rng: np.random.Generator) -> list[float]:
    a = rng.normal(size=(3, 3)) * rng.uniform(1e-4, 1.0, size=3)
    return (a @ a.T + 1e-6 * np.eye(3)).ravel().tolist()


def test_one_update_in_floats_is_the_numpy_algebra() -> None:
    rng = np.random.default_rng(7)
    for _ in range(500):
        theta = rng.normal(size=3).tolist()
        cov = _random_covariance(rng)
        phi = (float(rng.normal()), float(rng.normal()), 1.0)
        residual, noise = float(rng.normal() * 3.0), float(rng.uniform(1e-6, 1.0))
        clip = float(rng.uniform(0.5, 4.0))
        fast_t, fast_p = list(theta), list(cov)
        ref_t, ref_p = list(theta), list(cov)
        kalman3(fast_t, fast_p, phi, residual, noise, clip)
        kalman3_reference(ref_t, ref_p, phi, residual, noise, clip)
        np.testing.assert_allclose(fast_t, ref_t, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(fast_p, ref_p, rtol=1e-10, atol=1e-15)
        assert fast_t != theta  # it did learn


def test_the_maps_read_out_as_their_regressors_say() -> None:
    """speed, spread, data_sheet and current, written out per branch, against phi . theta
    and phi P phi in numpy on learnt (non-diagonal) states."""
    rng = np.random.default_rng(11)
    cfg = DiagnosisConfig()
    drive = DriveModel(full_force_n=100.0, k_thrust=0.05, k_torque=0.004, time_constant_s=0.2)
    smap, load = SpeedMap(cfg, 40.0), LoadModel(drive, cfg, 40.0)
    for _ in range(300):
        x = float(rng.uniform(-40.0, 40.0))
        smap.learn(0.1, x, float(rng.normal()), 0.5)
        load.learn(0.1, x, load.current(x) * float(rng.uniform(0.9, 1.1)))
        for probe in (x, -x, 0.0, float(rng.uniform(-50.0, 50.0))):
            phi = np.array([max(probe, 0.0), min(probe, 0.0), 1.0])
            P = np.array(smap.P).reshape(3, 3)
            expect = float(phi @ np.array(smap.theta)) if probe else 0.0
            assert smap.speed(probe) == pytest.approx(expect, rel=1e-12, abs=1e-12)
            assert smap.spread(probe) == pytest.approx(
                math.sqrt(max(float(phi @ P @ phi), 0.0)), rel=1e-9, abs=1e-12
            )
            if probe:
                assert smap.data_sheet(smap.speed(probe)) == pytest.approx(probe, rel=1e-9)
            nu = abs(probe) / load.n_full
            f = np.array([nu**3, math.copysign(nu * nu, probe), 1.0])
            assert load.current(probe) == pytest.approx(
                load.idle_a + load.load_a * float(f @ np.array(load.theta)), rel=1e-12
            )
    assert smap.P[1] != 0.0 and load.P[1] != 0.0  # the states are correlated: a real check


@pytest.mark.parametrize(
    ("name", "cause"),
    [("supply-station-drawn", Cause.JAMMED), ("cybership2-station-drawn", Cause.DRIVE_DEAD)],
)
def test_a_run_with_the_numpy_maps_is_the_run_with_the_float_maps(
    name: str, cause: Cause, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Whole runs (a propeller jammed or its drive dead, and the diagnosis naming it; the
    supply vessel cut to 320 s) with the maps learning through the reference algebra and
    through the floats: every recorded column within 1e-9."""
    sc = load_scenario(name)
    events = tuple(dataclasses.replace(ev, cause=cause) for ev in sc.faults.events)
    sc = dataclasses.replace(
        sc, duration_s=min(sc.duration_s, 320.0), seed=3,
        faults=dataclasses.replace(sc.faults, events=events),
    )  # fmt: skip
    fast = run_mode(sc, Mode.FTCAP)
    monkeypatch.setattr(shaft_channel, "kalman3", kalman3_reference)
    ref = run_mode(sc, Mode.FTCAP)
    named = HYPOTHESIS_CODES[Hypothesis(cause.value)]
    assert any(
        np.any(v == named) for k, v in fast.columns.items() if k.startswith("drive_")
    )  # the diagnosis named the fault: its decisions are compared too
    for key, col in ref.columns.items():
        if key == "solve_us":
            continue
        np.testing.assert_allclose(fast.columns[key], col, rtol=1e-9, atol=1e-9, err_msg=key)
