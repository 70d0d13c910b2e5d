"""Thruster geometry -> B against literal matrices, and configuration errors that name the key."""

from __future__ import annotations

import math
import re
import tomllib

import numpy as np
import pytest

from ftcap_hil.config.vessel import thrusters_from_table
from ftcap_hil.core.effectiveness.geometry import effectiveness, paper_four_thrusters
from ftcap_hil.core.errors import ConfigError
from tests.support.vessels import (
    EQ22_L03,
    EQ22_L05,
    S,
    eight_thrusters,
    six_thrusters,
)


@pytest.mark.parametrize(("l_m", "expected"), [(0.3, EQ22_L03), (0.5, EQ22_L05)])
def test_paper_vessel_is_eq22(l_m: float, expected: np.ndarray) -> None:
    B = effectiveness(paper_four_thrusters(l_m=l_m))
    assert B.shape == (3, 4)
    np.testing.assert_allclose(B, expected, rtol=0, atol=1e-15)


def test_paper_preset_from_toml_is_eq22_with_eq26_limits() -> None:
    ths = thrusters_from_table(tomllib.loads('[vessel]\npreset = "paper-4.2"\nl = 0.5\n')["vessel"])
    np.testing.assert_allclose(effectiveness(ths), EQ22_L05, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(ths.u_min, [-0.1] * 4)
    np.testing.assert_array_equal(ths.u_max, [0.1] * 4)
    np.testing.assert_array_equal(ths.max_step(0.2827), [0.09] * 4)


def test_six_thruster_vessel() -> None:
    ths = six_thrusters()
    B = effectiveness(ths)
    assert ths.m == 6
    assert ths.names == [
        "stern_port",
        "stern_stbd",
        "bow_tunnel_fwd",
        "bow_tunnel_aft",
        "diag_port",
        "diag_stbd",
    ]
    assert B.shape == (3, 6)
    assert np.linalg.matrix_rank(B) == 3
    # Columns by hand: [cos a, sin a, x sin a - y cos a].
    expected = np.array(
        [
            [1.0, 1.0, 0.0, 0.0, S, S],
            [0.0, 0.0, 1.0, 1.0, S, -S],
            [0.5, -0.5, 1.2, 0.8, 0.6 * S, -0.6 * S],
        ]
    )
    np.testing.assert_allclose(B, expected, rtol=0, atol=1e-15)
    # rate_max is per second, step_max per cycle, neither means unlimited.
    np.testing.assert_allclose(ths.max_step(0.1), [0.5, 0.5, 0.2, 0.2, math.inf, 0.3])
    np.testing.assert_array_equal(ths.u_min, [-2.0, -2.0, -1.0, -1.0, -1.5, -1.5])
    np.testing.assert_array_equal(ths.u_max, [4.0, 4.0, 1.0, 1.0, 1.5, 1.5])


def test_eight_thruster_vessel() -> None:
    ths = eight_thrusters()
    B = effectiveness(ths)
    assert B.shape == (3, 8)
    assert np.linalg.matrix_rank(B) == 3
    # D1 at (2, -1) pushing to port: [0, -1, 2 * (-1) - (-1) * 0].
    np.testing.assert_allclose(B[:, 6], [0.0, -1.0, -2.0], rtol=0, atol=1e-15)
    # D2 at (-1, 0.5) along (-3, 4)/5: [-0.6, 0.8, -1 * 0.8 - 0.5 * (-0.6)].
    np.testing.assert_allclose(B[:, 7], [-0.6, 0.8, -0.5], rtol=0, atol=1e-15)
    # C1 at (1, 1) along (1, 1)/sqrt 2: moment 1 * S - 1 * S = 0.
    np.testing.assert_allclose(B[:, 4], [S, S, 0.0], rtol=0, atol=1e-15)
    # T2 at (-1.5, 0) pushing to starboard: moment -1.5.
    np.testing.assert_allclose(B[:, 3], [0.0, 1.0, -1.5], rtol=0, atol=1e-15)
    np.testing.assert_allclose(ths.max_step(0.2), [1.0, 1.0] + [math.inf] * 6)


@pytest.mark.parametrize(
    ("direction", "angle_deg", "column"),
    [  # the column of B at (x, y) = (0.7, -0.2): (cos a, sin a, x sin a - y cos a)
        ([1.0, 1.0], 45.0, [S, S, 0.9 * S]),
        ([0.0, 2.0], 90.0, [0.0, 1.0, 0.7]),
        ([-1.0, 0.0], 180.0, [-1.0, 0.0, -0.2]),
        ([3.0, -4.0], -53.13010235415598, [0.6, -0.8, -0.44]),
    ],
)
def test_direction_equals_angle(
    direction: list[float], angle_deg: float, column: list[float]
) -> None:
    base = {"name": "t", "x": 0.7, "y": -0.2, "u_min": -1.0, "u_max": 1.0}
    by_dir = thrusters_from_table({"thruster": [{**base, "direction": direction}]})
    by_angle = thrusters_from_table({"thruster": [{**base, "angle_deg": angle_deg}]})
    for ths in (by_dir, by_angle):
        assert ths.thrusters[0].angle_rad == pytest.approx(math.radians(angle_deg), abs=1e-12)
        np.testing.assert_allclose(effectiveness(ths), np.array([column]).T, rtol=0, atol=1e-12)


def _one(**overrides: object) -> dict[str, object]:
    entry: dict[str, object] = {
        "name": "T",
        "x": 0.0,
        "y": 0.0,
        "angle_deg": 0.0,
        "u_min": -1.0,
        "u_max": 1.0,
    }
    entry.update(overrides)
    return {
        "thruster": [
            {"name": "OK", "x": 1.0, "y": 0.0, "angle_deg": 90.0, "u_min": -1.0, "u_max": 1.0},
            entry,
        ]
    }


TH1 = re.escape("[[vessel.thruster]][1]")


def test_missing_u_max_names_key() -> None:
    table = _one()
    del table["thruster"][1]["u_max"]  # type: ignore[index]
    with pytest.raises(ConfigError, match=TH1 + r" u_max: missing"):
        thrusters_from_table(table)


def test_positive_u_min_names_key_and_value() -> None:
    with pytest.raises(ConfigError, match=TH1 + r" need u_min <= 0 <= u_max, got 0\.5"):
        thrusters_from_table(_one(u_min=0.5))


def test_rate_and_step_both_given_names_both_keys() -> None:
    with pytest.raises(ConfigError, match=TH1 + r" give rate_max or step_max, not both"):
        thrusters_from_table(_one(rate_max=1.0, step_max=0.1))


@pytest.mark.parametrize("key", ["rate_max", "step_max"])
def test_non_positive_rate_names_key(key: str) -> None:
    with pytest.raises(ConfigError, match=TH1 + rf" {key}: expected a finite number > 0, got -1"):
        thrusters_from_table(_one(**{key: -1.0}))


def test_non_number_names_key_and_value() -> None:
    with pytest.raises(ConfigError, match=TH1 + r" x: expected a finite number, got 'abc'"):
        thrusters_from_table(_one(x="abc"))


def test_zero_direction_names_key() -> None:
    entry = _one(direction=[0.0, 0.0])
    del entry["thruster"][1]["angle_deg"]  # type: ignore[index]
    with pytest.raises(ConfigError, match=TH1 + r" direction: zero vector"):
        thrusters_from_table(entry)


def test_duplicate_names_named() -> None:
    with pytest.raises(ConfigError, match=r"\[vessel\] thruster: duplicate names .*'OK'"):
        thrusters_from_table(_one(name="OK"))


def test_unknown_preset_names_key_and_value() -> None:
    message = "[vessel] preset: 'paper-9.9' is not one of 'paper-4.2'"
    with pytest.raises(ConfigError, match=re.escape(message)):
        thrusters_from_table({"preset": "paper-9.9"})


def test_empty_thruster_list_names_key() -> None:
    message = "[vessel] thruster: expected at least one [[thruster]]"
    with pytest.raises(ConfigError, match=re.escape(message)):
        thrusters_from_table({"thruster": []})


@pytest.mark.parametrize(
    ("key", "value"),
    [("u_limit", -0.1), ("step_limit", -0.09), ("rate_limit", -1.0), ("l", 0.0), ("u_limit", 0.0)],
)
def test_preset_rejects_bad_numbers(key: str, value: float) -> None:
    with pytest.raises(ConfigError, match=key):
        thrusters_from_table({"preset": "paper-4.2", key: value})
