"""Null-space dither and recovery probes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ftcap_hil.core.allocation.excitation import Excitation, ExcitationConfig
from ftcap_hil.core.effectiveness.geometry import ThrusterSet, effectiveness, paper_four_thrusters
from tests.support.vessels import eight_thrusters, six_thrusters

VESSELS = {"paper4": paper_four_thrusters, "six": six_thrusters, "eight": eight_thrusters}


def setup(name: str) -> tuple[ThrusterSet, np.ndarray, np.ndarray]:
    ths = VESSELS[name]()
    return ths, effectiveness(ths), np.maximum(np.abs(ths.u_min), np.abs(ths.u_max))


@st.composite
def vessel_and_delta(draw: st.DrawFn) -> tuple[str, np.ndarray, np.ndarray]:
    name = draw(st.sampled_from(sorted(VESSELS)))
    m = VESSELS[name]().m
    delta = np.array(draw(st.lists(st.floats(0.2, 1.0), min_size=m, max_size=m)))
    # Take out at most m - 3 thrusters (the rest keeps a 3-dof span in these layouts).
    n_dead = draw(st.integers(0, m - 4))
    dead = np.zeros(m, dtype=bool)
    dead[draw(st.permutations(range(m)))[:n_dead]] = True
    return name, np.where(dead, 0.0, delta), dead


@settings(max_examples=80, deadline=None)
@given(case=vessel_and_delta(), amplitude=st.floats(0.01, 0.5), seed=st.integers(0, 100))
def test_dither_in_live_null_space_with_peak_amplitude(
    case: tuple[str, np.ndarray, np.ndarray], amplitude: float, seed: int
) -> None:
    name, delta_hat, dead = case
    ths, B, u_range = setup(name)
    exc = Excitation(
        B,
        u_range,
        ExcitationConfig(dither_amplitude=amplitude, dither_period=1, probe_interval=0, seed=seed),
    )
    live = ~dead
    for _ in range(8):
        out = exc(delta_hat, dead)
        u_pref = out.u_pref
        wrench = B[:, live] @ (delta_hat[live] * u_pref[live])
        assert np.linalg.norm(wrench) < 1e-9
        assert np.all(u_pref[dead] == 0.0)
        np.testing.assert_array_equal(out.probe_limit, np.zeros(ths.m))
        peak = np.max(np.abs(u_pref) / u_range)
        assert peak == pytest.approx(amplitude, rel=1e-12)
        assert np.all(np.abs(u_pref) <= amplitude * u_range * (1 + 1e-12))


def test_dither_holds_each_level_for_its_period_and_changes() -> None:
    ths, B, u_range = setup("six")
    exc = Excitation(B, u_range, ExcitationConfig(dither_period=3, probe_interval=0))
    dead = np.zeros(ths.m, dtype=bool)
    outs = [exc(np.ones(ths.m), dead).u_pref.copy() for _ in range(30)]
    for level in range(10):
        block = outs[3 * level : 3 * level + 3]
        for o in block[1:]:
            np.testing.assert_array_equal(o, block[0])
    distinct = {tuple(np.round(o, 12)) for o in outs}
    assert len(distinct) > 2  # a PRBS, not a constant


def test_dead_thruster_probe_windows() -> None:
    ths, B, u_range = setup("paper4")
    cfg = ExcitationConfig(probe_amplitude=0.2, probe_interval=10, probe_length=4)
    exc = Excitation(B, u_range, cfg)
    delta_hat = np.array([1.0, 0.0, 1.0, 1.0])
    dead = np.array([False, True, False, False])
    amp = 0.2 * u_range[1]
    for cycle in range(2 * cfg.probe_interval):
        out = exc(delta_hat, dead)
        phase = cycle % cfg.probe_interval
        if phase < cfg.probe_length:
            sign = 1.0 if phase % 2 == 0 else -1.0
            assert out.u_pref[1] == sign * amp
            np.testing.assert_array_equal(out.probe_limit, [0.0, amp, 0.0, 0.0])
        else:
            assert out.u_pref[1] == 0.0
            np.testing.assert_array_equal(out.probe_limit, np.zeros(4))
        # The live thrusters keep dithering inside their own null space (rank 3 of 3: none).
        np.testing.assert_array_equal(out.u_pref[~dead], np.zeros(3))


def test_probe_pulse_train_is_zero_mean() -> None:
    ths, B, u_range = setup("six")
    cfg = ExcitationConfig(probe_interval=20, probe_length=4)
    exc = Excitation(B, u_range, cfg)
    dead = np.array([False, False, True, False, False, True])
    delta_hat = np.where(dead, 0.0, 1.0)
    probes = np.array([exc(delta_hat, dead).u_pref[dead] for _ in range(40)])
    np.testing.assert_allclose(probes.sum(axis=0), 0.0, atol=1e-15)
    assert np.count_nonzero(probes[:, 0]) == 8


def test_no_advance_holds_sequence() -> None:
    """Without a new estimation sample the dither level and the probe phase stay put."""
    ths, B, u_range = setup("six")
    cfg = ExcitationConfig(dither_period=1, probe_interval=10, probe_length=2)
    held = Excitation(B, u_range, cfg)
    ref = Excitation(B, u_range, cfg)
    dead = np.array([False, False, False, False, False, True])
    delta_hat = np.where(dead, 0.0, 1.0)
    first = held(delta_hat, dead, advance=False)
    u0, lim0 = first.u_pref.copy(), first.probe_limit.copy()
    for _ in range(5):
        out = held(delta_hat, dead, advance=False)
        np.testing.assert_array_equal(out.u_pref, u0)
        np.testing.assert_array_equal(out.probe_limit, lim0)
    # Advancing afterwards replays the same sequence as an excitation that never paused.
    for _ in range(12):
        np.testing.assert_array_equal(held(delta_hat, dead).u_pref, ref(delta_hat, dead).u_pref)


def test_zero_amplitudes_disable() -> None:
    ths, B, u_range = setup("six")
    exc = Excitation(B, u_range, ExcitationConfig(dither_amplitude=0.0, probe_amplitude=0.0))
    dead = np.array([False, False, True, False, False, False])
    for _ in range(120):
        out = exc(np.where(dead, 0.0, 0.9), dead)
        np.testing.assert_array_equal(out.u_pref, np.zeros(ths.m))
        np.testing.assert_array_equal(out.probe_limit, np.zeros(ths.m))


def test_zero_probe_interval_disables_probes() -> None:
    ths, B, u_range = setup("paper4")
    exc = Excitation(B, u_range, ExcitationConfig(probe_interval=0))
    dead = np.array([True, False, False, False])
    for _ in range(60):
        out = exc(np.array([0.0, 1.0, 1.0, 1.0]), dead)
        assert out.u_pref[0] == 0.0
        assert not out.probe_limit.any()


def test_no_null_space_no_dither() -> None:
    """Three live thrusters of the paper vessel span the wrench space: nothing to dither."""
    _ths, B, u_range = setup("paper4")
    exc = Excitation(B, u_range)
    out = exc(np.array([1.0, 1.0, 1.0, 0.0]), np.array([False, False, False, True]))
    np.testing.assert_array_equal(out.u_pref[:3], np.zeros(3))


@pytest.mark.parametrize(
    "kwargs",
    [
        {"dither_amplitude": -0.1},
        {"probe_amplitude": -0.1},
        {"dither_period": 0},
        {"probe_length": 0},
        {"probe_interval": -1},
    ],
)
def test_config_errors(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError, match="excitation"):
        ExcitationConfig(**kwargs)
