"""timeseries.csv: the columns defined once by name and filled by name by both recorders."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.status import AllocatorStatus, Mode
from ftcap_hil.report.flight import NOT_ON_MAVLINK, FlightRecorder
from ftcap_hil.report.records import Rows, column_names
from ftcap_hil.runtime.offline import run_mode

SC = load_scenario("paper-4.2-ex1")


def test_the_columns_of_a_four_thruster_vessel() -> None:
    names = column_names(SC)
    assert names[:10] == ["t", "north", "east", "psi", "u", "v", "r", "ref_north", "ref_east",
                          "ref_psi"]  # fmt: skip
    groups = ("faulty", "dead", "delta_std", "observable", "drive")
    assert names[-20:] == [f"{g}_{i}" for g in groups for i in range(1, 5)]
    assert len(names) == 1 + 6 + 3 + 3 + 3 + 6 * 4 + 3 + 5 + 5 * 4 == len(set(names))


def test_a_row_is_filled_by_group_and_the_rest_is_nan() -> None:
    rows = Rows(SC)
    rows.add(t=1.5, delta_hat=[1.0, 0.5, 1.0, 0.0], fallback=True)
    c = {k: v[0] for k, v in rows.columns().items()}
    assert (c["t"], c["delta_hat_2"], c["delta_hat_4"], c["fallback"]) == (1.5, 0.5, 0.0, 1.0)
    assert math.isnan(c["north"]) and math.isnan(c["delta_std_1"])
    with pytest.raises(ValueError, match="delta_hat: expected 4 values"):
        rows.add(delta_hat=[1.0])
    with pytest.raises(ValueError, match="v_dem: expected 3 values"):
        rows.add(v_dem=0.0)
    with pytest.raises(KeyError):
        rows.add(delta_hats=[1.0] * 4)


def test_the_offline_record_carries_the_kalman_uncertainty() -> None:
    sc = replace(SC, duration_s=3.0)
    rec = run_mode(sc, Mode.FTCAP)
    std = np.column_stack([rec.columns[f"delta_std_{i}"] for i in range(1, 5)])
    obs = np.column_stack([rec.columns[f"observable_{i}"] for i in range(1, 5)])
    assert np.all(std[0] == 0.0)  # before the first sample: the stage's initial estimate
    assert std[1] == pytest.approx(np.full(4, 0.05), abs=1e-3)  # estimator.initial_delta_std
    assert np.all(np.isfinite(std)) and np.all(std[1:] > 0.0)
    assert np.all(np.isnan(obs[0])) and set(np.unique(obs[1:])) <= {0.0, 1.0}  # no decision yet
    cap = run_mode(sc, Mode.CAP)
    assert np.all(cap.columns["delta_std_1"] == 0.0)  # CAP: delta_hat = 1, known exactly
    assert np.all(np.isnan(cap.columns["observable_1"]))  # no decision stage


def test_the_flight_record_takes_what_ftcap_status_carries() -> None:
    rec = FlightRecorder(SC)
    status = AllocatorStatus.checked(
        delta_hat=(0.9, 1.0, 1.0, 1.0),
        f_hat=(0.0,) * 4,
        delta_std=(0.05, 0.01, 0.01, 0.01),
        faulty=(True, False, False, False),
    )
    x = np.zeros(6)
    rec.add(0.0, x, np.zeros(3), np.zeros(3), status, None)
    rec.add(0.1, x, np.zeros(3), np.zeros(3), replace(status, delta_hat=(1.0,) * 3), None)
    run = rec.finish("ftcap", 0.1)
    c = {k: v[0] for k, v in run.columns.items()}
    assert (c["delta_std_1"], c["faulty_1"], c["faulty_2"], c["fallback"]) == (0.05, 1.0, 0.0, 0.0)
    for group in NOT_ON_MAVLINK:
        name = group if group in c else f"{group}_1"
        assert math.isnan(c[name]), name
    other = {k: v[1] for k, v in run.columns.items()}  # a status for 3 thrusters: not ours
    assert math.isnan(other["delta_hat_1"]) and math.isnan(other["delta_std_1"])
