"""Scenario files: shipped ones load, the paper's example 1 is eqs. (25)-(28), errors name
the key and the value."""

from __future__ import annotations

import math
import re
import tomllib

import numpy as np
import pytest

from ftcap_hil.config.scenario import load_scenario, parse_scenario, shipped_scenarios
from ftcap_hil.core.effectiveness.geometry import effectiveness
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.models.plants import LinearPlant, SurfaceVessel
from ftcap_hil.core.status import Mode
from tests.support.vessels import EQ22_L03

BASE = """
[scenario]
name = "unit"
dt = 0.5
duration = 10.0

[plant]
kind = "vessel"

[vessel]
preset = "paper-4.2"

[[reference]]
from = 0.0
value = [1.0, 0.0, 0.0]

[[fault]]
from = 2.0
until = 4.0
thruster = 2
delta = 0.5
[[fault]]
from = 3.0
delta = [1.0, 1.0, 0.0, 1.0]
bias = [0.0, 0.0, 0.01, 0.0]
"""


def parse(text: str):
    return parse_scenario(tomllib.loads(text), "unit.toml")


def test_every_shipped_scenario_loads() -> None:
    names = shipped_scenarios()
    assert "paper-4.2-ex1" in names and "paper-4.1" in names
    for name in names:
        sc = load_scenario(name)
        assert sc.name == name
        k, m = sc.B.shape
        assert m == sc.thrusters.m
        assert sc.steps > 0 and sc.dt_s > 0
        assert sc.reference[0].value.shape == (k,)
        assert sc.faults.at(0.0).delta.shape == (m,)
        assert sc.x0.shape == (1 if isinstance(sc.plant, LinearPlant) else 6,)


def test_paper_ex1_is_eqs_25_to_28() -> None:
    sc = load_scenario("paper-4.2-ex1")
    assert isinstance(sc.plant, SurfaceVessel)
    assert sc.dt_s == 0.2827
    np.testing.assert_allclose(sc.B, EQ22_L03, atol=1e-15)
    np.testing.assert_array_equal(sc.thrusters.u_max, [0.1] * 4)  # eq. (26)
    np.testing.assert_array_equal(sc.thrusters.u_min, [-0.1] * 4)
    np.testing.assert_allclose(sc.thrusters.max_step(sc.dt_s), [0.09] * 4)
    # Eqs. (27)-(28).
    for t, delta, f in [
        (0.0, [1, 1, 1, 1], [0, 0, 0, 0]),
        (11.9, [1, 1, 1, 1], [0, 0, 0, 0]),
        (12.0, [0.9, 1, 1, 1], [0.01, 0, 0, 0]),
        (100.0, [0.9, 1, 1, 1], [0.01, 0, 0, 0]),
        (199.9, [0.9, 1, 1, 1], [0.01, 0, 0, 0]),
        (200.1, [0.8, 1, 0, 1], [0, 0, 0.01, 0]),
        (300.0, [0.8, 1, 0, 1], [0, 0, 0.01, 0]),
        (699.0, [0.8, 1, 0, 1], [0, 0, 0.01, 0]),
    ]:
        truth = sc.faults.at(t)
        np.testing.assert_array_equal(truth.delta, delta, err_msg=f"t={t}")
        np.testing.assert_array_equal(truth.f, f, err_msg=f"t={t}")
    # Eq. (25).
    for t, ref in [
        (0.0, [0, 0, 0]),
        (11.9, [0, 0, 0]),
        (12.0, [2, 0, 0]),
        (100.0, [2, 0, 0]),
        (300.0, [2, 2, math.pi]),
        (499.0, [2, 2, math.pi]),
        (600.0, [0, 0, 0]),
    ]:
        np.testing.assert_array_equal(sc.reference_at(t), ref, err_msg=f"t={t}")
    assert [a for a, _ in sc.phases()] == [0.0, 12.0, 200.0]
    assert sc.core.mode is Mode.FTCAP


def test_fault_events_override_in_order() -> None:
    sc = parse(BASE)
    np.testing.assert_array_equal(sc.faults.at(1.0).delta, [1, 1, 1, 1])
    np.testing.assert_array_equal(sc.faults.at(2.5).delta, [1, 0.5, 1, 1])  # thruster 2: 1-based
    # From 3 s the vector event overrides; until 4 s the single-thruster one would apply too
    # but comes first in the file.
    np.testing.assert_array_equal(sc.faults.at(3.5).delta, [1, 1, 0, 1])
    np.testing.assert_array_equal(sc.faults.at(5.0).f, [0, 0, 0.01, 0])
    assert sc.faults.change_times() == [2.0, 3.0, 4.0]
    assert sc.with_mode(Mode.CAP).core.mode is Mode.CAP


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            'name = "unit"',
            'mode = "turbo"',
            "[scenario] mode: 'turbo' is not one of 'none', 'cap', 'ftcap'",
        ),
        (
            "delta = 0.5",
            "delta = 1.5",
            "[[fault]][0] delta: expected a finite number in 0..1, got 1.5",
        ),
        (
            "delta = 0.5",
            "delta = -0.1",
            "[[fault]][0] delta: expected a finite number in 0..1, got -0.1",
        ),
        (
            "thruster = 2",
            "thruster = 5",
            "[[fault]][0] thruster: expected an integer in 1..4, got 5",
        ),
        (
            "thruster = 2",
            "thruster = 0",
            "[[fault]][0] thruster: expected an integer in 1..4, got 0",
        ),
        ('kind = "vessel"', 'kind = "blimp"', "[plant] kind: 'blimp' is not one of 'linear'"),
        ("dt = 0.5", "dt = -0.5", "[scenario] dt: expected a finite number > 0, got -0.5"),
        (
            "value = [1.0, 0.0, 0.0]",
            "value = [1.0, 0.0]",
            "[[reference]][0] value: expected 3 finite numbers, got [1.0, 0.0]",
        ),
        (
            'preset = "paper-4.2"',
            'preset = "paper-4.3"',
            "[vessel] preset: 'paper-4.3' is not one of 'paper-4.2'",
        ),
        ("duration = 10.0", "", "[scenario] duration: missing"),
        ("until = 4.0", "until = 2.0", "[[fault]][0] until: expected a time after from = 2, got 2"),
    ],
)
def test_errors_name_key_and_value(old: str, new: str, message: str) -> None:
    assert old in BASE
    with pytest.raises(ConfigError, match=re.escape(f"unit.toml: {message}")):
        parse(BASE.replace(old, new, 1))


@pytest.mark.parametrize(
    ("table", "key"),
    [("estimator", "windw"), ("allocator", "backnd"), ("excitation", "dither_amp")],
)
def test_unknown_config_key_named(table: str, key: str) -> None:
    with pytest.raises(ConfigError, match=rf"unit\.toml: \[{table}\] unknown key '{key}'"):
        parse(BASE + f"\n[{table}]\n{key} = 3\n")


def test_bad_config_value_named() -> None:
    with pytest.raises(ConfigError, match=r"estimator.*window.*1"):
        parse(BASE + "\n[estimator]\nwindow = 1\n")


def test_config_tables_reach_the_core() -> None:
    sc = parse(
        BASE + '\n[estimator]\nwindow = 7\n[allocator]\nbackend = "daqp"\n'
        "[excitation]\nprobe_interval = 9\n"
    )
    assert sc.core.estimator.window == 7
    assert sc.core.allocator.backend == "daqp"
    assert sc.core.excitation.probe_interval == 9


def test_effectiveness_matches_vessel() -> None:
    sc = parse(BASE)
    np.testing.assert_array_equal(sc.B, effectiveness(sc.thrusters))


def test_unknown_scenario_name() -> None:
    with pytest.raises(ConfigError, match="'no-such-scenario'"):
        load_scenario("no-such-scenario")
