"""[uncertainty]: the model error and the truth's departures from the data sheets drawn per
seed (config/uncertainty.py), and what the allocator is told (config/realistic.py)."""

from __future__ import annotations

import tomllib
from importlib import resources

import numpy as np
import pytest

from ftcap_hil.config.presets import load_preset
from ftcap_hil.config.scenario import parse_scenario
from ftcap_hil.config.uncertainty import Uncertainty
from ftcap_hil.core.errors import ConfigError

RANGES = {
    "mass": 0.2, "added_mass": 0.2, "damping": 0.3, "angle_deg": 5.0, "angled": 2,
    "thrust_coefficient": 0.1, "time_constant": 0.25, "noise": 0.5, "sensor_bias_rel": 0.5,
    "delay_s": 0.2, "dropout_p": 0.05, "sea_state": 0.2,
}  # fmt: skip


def _doc(seed: int, uncertainty: dict | None = RANGES) -> dict:
    """The shipped CyberShip II station keeping, 2 s, its fixed [mismatch] model error
    replaced by drawn ones (the drives' data-sheet errors stay)."""
    path = resources.files("ftcap_hil.data.scenarios").joinpath("cybership2-station.toml")
    doc = tomllib.loads(path.read_text())
    doc["scenario"].update(seed=seed, duration=2.0)
    for key in ("mass", "damping", "angle_deg"):
        doc["mismatch"].pop(key)
    if uncertainty is not None:
        doc["uncertainty"] = dict(uncertainty)
    return doc


def test_each_seed_draws_its_own_vessel_within_the_ranges_and_the_same_again() -> None:
    u = Uncertainty(**RANGES)
    draws = [u.draw(seed, 6) for seed in range(200)]
    assert u.draw(7, 6).describe() == draws[7].describe()  # the same seed, the same vessel
    assert u.draw(8, 6).describe() != draws[7].describe()
    mass = np.array([d.mass for d in draws])
    assert 0.8 <= mass.min() < 0.85 and 1.15 < mass.max() <= 1.2  # uniform over +-20 %
    assert all(len(d.angle_deg) == 2 and all(abs(a) <= 5.0 for a in d.angle_deg.values())
               for d in draws)  # fmt: skip
    gains = np.array([d.thrust_gain for d in draws])
    assert gains.shape == (200, 6) and np.all(np.abs(gains - 1.0) <= 0.1)
    assert len({round(float(g), 9) for g in gains[0]}) == 6  # per thruster, not one factor
    assert all(0.0 <= d.delay_s <= 0.2 and 0.0 <= d.dropout_p <= 0.05 for d in draws)
    assert not Uncertainty().any and Uncertainty(delay_s=0.1).any


def test_the_allocator_is_told_the_data_sheets_while_the_truth_departs_from_them() -> None:
    preset = load_preset("cybership2")
    sc = parse_scenario(_doc(seed=3), "u.toml")
    drawn = Uncertainty(**RANGES).draw(3, preset.thrusters.m)
    sheet_lag = preset.time_constants_s
    # told: the preset's lag and noise; the truth: the draw's
    assert sc.core.thruster_lag_s == pytest.approx(tuple(sheet_lag))
    np.testing.assert_allclose(sc.truth.bank.time_constant_s, sheet_lag * drawn.lag_factor)
    assert not np.allclose(sc.truth.bank.time_constant_s, sheet_lag)
    np.testing.assert_allclose(sc.truth.bank.forward_gain, drawn.thrust_gain)
    told_std = np.array(sc.core.estimator.measurement_std)
    np.testing.assert_allclose(sc.truth.sensor.noise_std, told_std * drawn.noise_factor)
    assert sc.truth.sensor.delay_s == pytest.approx(drawn.delay_s)
    # the sea: the truth's Hs drawn off the stated one, the wave model told the stated one
    stated = preset.environment.waves
    assert sc.truth.environment.waves.hs_m == pytest.approx(stated.hs_m * drawn.hs_factor)
    assert sc.core.estimator.wave_period_s == pytest.approx(stated.tp_s)
    # the model: mass and added mass drawn, the damping too, two thrusters turned
    m_true, m_told = preset.vessel.mass_kg, sc.plant.mass_kg
    assert m_told == pytest.approx(m_true * drawn.mass)
    assert sc.plant.X_udot == pytest.approx(preset.vessel.X_udot * drawn.mass * drawn.added_mass)
    pairs = zip(sc.thrusters.thrusters, preset.thrusters.thrusters, strict=True)
    turned = [i for i, (a, b) in enumerate(pairs) if a.angle_rad != b.angle_rad]
    assert sorted(turned) == sorted(drawn.angle_deg)


def test_another_seed_is_another_vessel_and_no_uncertainty_is_the_stated_one() -> None:
    a, b = parse_scenario(_doc(seed=1), "u.toml"), parse_scenario(_doc(seed=2), "u.toml")
    assert a.plant.mass_kg != b.plant.mass_kg
    assert not np.allclose(a.truth.bank.forward_gain, b.truth.bank.forward_gain)
    plain = parse_scenario(_doc(seed=1, uncertainty=None), "u.toml")
    preset = load_preset("cybership2")
    assert plain.plant.mass_kg == preset.vessel.mass_kg  # no [mismatch] mass, nothing drawn
    np.testing.assert_array_equal(plain.truth.bank.time_constant_s, preset.time_constants_s)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"uncertainty": {"mass": 0.2, "masss": 0.1}}, r"\[uncertainty\] unknown key 'masss'"),
        ({"uncertainty": {"damping": -0.1}}, r"\[uncertainty\] damping"),
        ({"uncertainty": {"mass": 0.2}, "mismatch": {"mass": 0.2}},
         r"\[mismatch\] mass: the model error is drawn"),
    ],
)  # fmt: skip
def test_uncertainty_is_read_strictly(change: dict, message: str) -> None:
    doc = _doc(seed=1, uncertainty=None)
    for table, values in change.items():
        doc.setdefault(table, {}).update(values)
    with pytest.raises(ConfigError, match=rf"u\.toml.*{message}"):
        parse_scenario(doc, "u.toml")


def test_a_delayed_sensor_runs_from_the_initial_state_until_its_first_delivery() -> None:
    """A drawn (or stated) sensor delay longer than a step delivers nothing at 0 s: the
    closed loop holds the state it was set up in until then (it raised IndexError)."""
    from ftcap_hil.core.status import Mode
    from ftcap_hil.runtime.offline import run_mode

    doc = _doc(seed=0, uncertainty=None)
    doc["sensor"] = {"delay_s": 0.35}
    doc["scenario"]["duration"] = 3.0
    rec = run_mode(parse_scenario(doc, "u.toml"), Mode.FTCAP)
    assert rec.t.size == 30 and np.isfinite(rec.columns["north"]).all()
