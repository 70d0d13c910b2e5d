"""A realistic scenario flown live sizes the setpoints' bound to its own vessel
(config/live_scenario.py): the paper vessel's 1000 N a component shrank a supply vessel's
station-keeping demands to nothing, and it drifted 7 m in a minute."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ftcap_hil.config.daemon import load_daemon_config
from ftcap_hil.config.live_scenario import SETPOINT_HEADROOM, wrench_bound
from ftcap_hil.config.mission import scenario_mission
from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.offline import run_mode


def test_the_supply_vessels_own_demands_pass_its_bound_and_the_paper_bound_would_shrink_them() -> (
    None
):
    sc = dataclasses.replace(load_scenario("supply-station-drawn"), duration_s=120.0)
    demand = np.array([run_mode(sc, Mode.FTCAP).columns[f"v_dem_{j}"] for j in (1, 2, 3)])
    peak = np.abs(demand).max(axis=1)
    assert (peak > 1000.0).all()  # the file's bound would cut every axis
    bound = np.array(wrench_bound(sc, (1000.0, 1000.0, 1000.0)))
    assert (peak < bound / 10.0).all()  # and the vessel's leaves them a decade of headroom


def test_the_bound_is_the_larger_of_the_files_and_the_vessels() -> None:
    cs2 = load_scenario("cybership2-station")
    th = cs2.thrusters
    capacity = np.abs(cs2.B) @ np.maximum(np.abs(th.u_min), np.abs(th.u_max))
    x, y, n = wrench_bound(cs2, (1000.0, 1000.0, 1000.0))
    expected = np.maximum(1000.0, SETPOINT_HEADROOM * capacity)
    assert (x, y, n) == pytest.approx(tuple(expected))
    assert (y, n) == (1000.0, 1000.0)  # a small vessel keeps the file's bound where larger
    assert wrench_bound(cs2, (1e9, 1e9, 1e9)) == (1e9, 1e9, 1e9)


def test_allocator_and_ground_station_told_the_scenario_take_its_bound() -> None:
    sc = load_scenario("supply-station-drawn")
    expected = wrench_bound(sc, (1000.0, 1000.0, 1000.0))
    ports = load_daemon_config(None, None, "supply-station-drawn").ports
    assert ports.mavlink is not None and ports.mavlink.wrench_limit == expected
    assert ports.zenoh is not None and ports.zenoh.wrench_limit == expected
    assert scenario_mission("supply-station-drawn").gcs.wrench_limit == expected
    # without a scenario the file's bound stands
    plain = load_daemon_config(None).ports
    assert plain.mavlink is not None and plain.mavlink.wrench_limit == (1000.0, 1000.0, 1000.0)
