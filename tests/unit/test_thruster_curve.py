"""Thruster curves (core) and the curve force map (CAN bridge): monotone tables, their
inverse, dead zone, asymmetry, the unidirectional option, the shipped T200 curve, and that a
wrong curve on the allocator's side gives thrust the allocator did not ask for."""

from __future__ import annotations

import tomllib
from importlib import resources

import numpy as np
import pytest

from bridges.can_io.force_map import RAW_MAX, CurveForceMap, ForceRawMap, NonFiniteCommand
from ftcap_hil.core.effectiveness.thruster_curve import CurveError, ThrusterCurve


def _t200() -> ThrusterCurve:
    path = resources.files("ftcap_hil").joinpath("data", "thrusters", "t200-12v.toml")
    return ThrusterCurve.from_mapping(tomllib.loads(path.read_text()), "t200-12v.toml")


def test_shipped_t200_curve_is_the_published_shape() -> None:
    c = _t200()
    assert (c.thrust_max_n, c.thrust_min_n) == (36.4, -28.6)  # 3.71 / 2.92 kgf at 12 V
    assert c.reversible
    assert c.thrust(np.array([-0.1, -0.05, 0.0, 0.05, 0.1])).tolist() == [0.0] * 5  # dead zone
    assert c.thrust(0.5) == pytest.approx(12.23)  # far below half of 36.4: not linear
    assert -c.thrust(-0.5) < c.thrust(0.5)  # reverse is weaker


def test_inverse_round_trips_and_saturates() -> None:
    c = _t200()
    t = np.linspace(-28.6, 36.4, 301)
    assert np.allclose(c.thrust(c.fraction_for(t)), t, atol=1e-9)
    assert c.fraction_for(np.array([100.0, -100.0])).tolist() == [1.0, -1.0]
    assert c.fraction_for(0.0) == 0.0
    assert 0.1 < float(c.fraction_for(1e-6)) < 0.1001  # a tiny thrust starts at the dead zone edge
    assert -0.1001 < float(c.fraction_for(-1e-6)) < -0.1


def test_unidirectional_curve_never_reverses() -> None:
    c = ThrusterCurve.from_table([0.0, 0.05, 1.0], [0.0, 0.0, 20.0], "forward-only")
    assert not c.reversible and c.thrust_min_n == 0.0
    assert c.thrust(np.array([-1.0, -0.2])).tolist() == [0.0, 0.0]
    assert c.fraction_for(np.array([-5.0, 10.0])).tolist() == [0.0, pytest.approx(0.525)]
    fmap = CurveForceMap.create([c, c])
    assert fmap.reversible == (False, False)
    assert fmap.to_raw([-3.0, 20.0]).tolist() == [0, RAW_MAX]


def test_polynomial_and_linear_constructors() -> None:
    q = ThrusterCurve.from_polynomial([0.0, 0.0, 10.0], [0.0, 0.0, 8.0], dead_zone=0.1)
    assert q.thrust(0.55) == pytest.approx(2.5, abs=0.01)  # (0.45 / 0.9)^2 * 10
    assert q.thrust(-1.0) == pytest.approx(-8.0)
    assert q.thrust(0.1) == 0.0
    one_way = ThrusterCurve.from_polynomial([0.0, 5.0])
    assert not one_way.reversible
    lin = ThrusterCurve.linear(10.0)
    assert lin.fraction_for(np.array([-5.0, 5.0])).tolist() == [-0.5, 0.5]


@pytest.mark.parametrize(
    ("fraction", "thrust", "what"),
    [
        ([-1.0, 1.0], [-1.0, 1.0], "point \\(0, 0\\)"),
        ([-1.0, 0.0, 0.5, 0.4], [-1.0, 0.0, 1.0, 2.0], "rise strictly within"),
        ([-1.0, 0.0, 1.0], [1.0, 0.0, 2.0], "rise with fraction"),
        ([0.0, 0.5, 0.8, 1.0], [0.0, 1.0, 1.0, 2.0], "outside the dead zone"),
        ([-1.0, 0.0], [-1.0, 0.0], "no forward thrust"),
        ([0.0, 1.5], [0.0, 1.0], "within \\[-1, 1\\]"),
        ([0.0, 1.0], [0.0, float("nan")], "finite"),
        ([0.0, 1.0], ["a", 1.0], "list of numbers"),
    ],
)
def test_bad_tables_are_refused_naming_the_curve(
    fraction: list[float], thrust: list[object], what: str
) -> None:
    with pytest.raises(CurveError, match=what):
        ThrusterCurve.from_table(fraction, thrust, "vessel.thrusters[2]")  # type: ignore[arg-type]


def test_mapping_needs_both_columns() -> None:
    with pytest.raises(CurveError, match="missing key"):
        ThrusterCurve.from_mapping({"fraction": [0.0, 1.0]}, "t.toml")


def test_curve_map_round_trip_within_one_count() -> None:
    c = _t200()
    fmap = CurveForceMap.create([c] * 3, deadband_n=0.05)
    u = np.array([12.0, -9.0, 0.01])
    raw = fmap.to_raw(u)
    assert raw[2] == 0  # inside the deadband
    back = fmap.to_force(raw)
    slope = 36.4 / 0.1  # steepest part of the table: N per unit fraction, upper bound
    assert np.allclose(back[:2], u[:2], atol=slope / RAW_MAX)
    with pytest.raises(NonFiniteCommand):
        fmap.to_raw([1.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="shape"):
        fmap.to_raw([1.0])


def test_linear_curve_map_equals_the_linear_map() -> None:
    lin = CurveForceMap.create([ThrusterCurve.linear(36.4)] * 2)
    plain = ForceRawMap.create([36.4, 36.4])
    # raw = round(u / 36.4 N * 8191), saturated at +-8191; under half a step is 0
    for u, raw in [([10.0, -20.0], [2250, -4501]), ([36.4, -36.4], [8191, -8191])]:
        assert lin.to_raw(u).tolist() == raw and plain.to_raw(u).tolist() == raw
    assert lin.to_raw([0.3, -0.001]).tolist() == plain.to_raw([0.3, -0.001]).tolist() == [68, 0]


def test_a_wrong_curve_on_the_allocator_side_is_a_thrust_error() -> None:
    """The allocator believes the thrusters are linear; the vessel's are T200s."""
    believed = ForceRawMap.create([36.4])
    physical = CurveForceMap.create([_t200()])
    asked = np.array([[5.0], [10.0], [20.0], [-10.0]])
    got = np.array([physical.to_force(believed.to_raw(u))[0] for u in asked])
    ratio = got / asked[:, 0]
    assert np.all(ratio < 0.8)  # every one well short of what was asked
    right = np.array([physical.to_force(physical.to_raw(u))[0] for u in asked])
    assert np.allclose(right, asked[:, 0], atol=0.01)


def test_the_shipped_wrong_curve_under_delivers_against_the_t200() -> None:
    path = resources.files("ftcap_hil").joinpath("data", "thrusters", "t200-12v-linear.toml")
    wrong = ThrusterCurve.from_mapping(tomllib.loads(path.read_text()), "t200-12v-linear.toml")
    true = _t200()
    assert (wrong.thrust_max_n, wrong.thrust_min_n) == (true.thrust_max_n, true.thrust_min_n)
    asked = np.linspace(2.0, 34.0, 17)
    got = true.thrust(wrong.fraction_for(asked))
    assert np.all(got < asked)  # short at every partial command
    assert float(got[0]) == 0.0  # 2 N asks for 5.5 % command: inside the dead zone


def test_scaled_keeps_the_shape_and_the_reverse_ratio() -> None:
    t200 = ThrusterCurve.from_table([-1.0, -0.1, 0.0, 0.1, 1.0], [-28.6, 0.0, 0.0, 0.0, 36.4])
    small = t200.scaled(0.1)
    assert small.thrust_max_n == 0.1 and small.thrust_min_n == pytest.approx(-0.1 * 28.6 / 36.4)
    assert np.array_equal(small.fraction, t200.fraction)
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(CurveError, match="scale to a thrust > 0 N"):
            t200.scaled(bad)
