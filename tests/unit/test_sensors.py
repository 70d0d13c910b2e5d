"""The odometry sensor: noise statistics, Gauss-Markov bias, rate, delay, dropouts, seeds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.sensors import Measurement, OdometrySensor, SensorConfig, gauss_markov_step

STD = np.array([0.02, 0.03, 0.005, 0.01, 0.015, 0.002])  # m, m, rad, m/s, m/s, rad/s
X = np.array([10.0, -5.0, 0.3, 0.5, 0.0, 0.01])


def collect(cfg: SensorConfig, steps: int, dt_s: float, x: np.ndarray = X) -> list[Measurement]:
    sensor = OdometrySensor(cfg)
    out: list[Measurement] = []
    for k in range(steps):
        out += sensor.step(k * dt_s, x)
    return out


def stacked(samples: list[Measurement]) -> np.ndarray:
    return np.array([np.concatenate([s.eta, s.nu]) for s in samples])


def test_white_noise_std_per_axis() -> None:
    y = stacked(collect(SensorConfig(noise_std=STD, seed=1), 20_000, 0.02))
    err = y - X
    # std of a sample std over n = 20000: std / sqrt(2n) = 0.5 %; 3 % is six of those
    np.testing.assert_allclose(err.std(axis=0), STD, rtol=0.03)
    assert np.all(np.abs(err.mean(axis=0)) < 4 * STD / math.sqrt(20_000))


def test_perfect_sensor_returns_the_state() -> None:
    [s] = collect(SensorConfig(), 1, 0.02)
    np.testing.assert_array_equal(np.concatenate([s.eta, s.nu]), X)
    assert (s.t_measured_s, s.t_delivered_s) == (0.0, 0.0)


def test_heading_is_wrapped() -> None:
    x = X.copy()
    x[2] = math.pi - 1e-4
    y = stacked(collect(SensorConfig(noise_std=[0, 0, 0.01, 0, 0, 0]), 2000, 0.02, x))
    assert np.all(np.abs(y[:, 2]) <= math.pi) and np.any(y[:, 2] < 0.0)


def test_gauss_markov_step_variance_from_the_formula() -> None:
    rng = np.random.default_rng(5)
    n, sigma, tau = 50_000, 0.2, 30.0
    b = np.zeros(n)
    for _ in range(10):  # 10 steps of tau / 10: at t = tau
        b = gauss_markov_step(
            b, tau / 10, np.full(n, tau), np.full(n, sigma), rng.standard_normal(n)
        )
    expected = sigma**2 * (1 - math.exp(-2.0))  # sigma^2 (1 - exp(-2 t / tau))
    assert b.var() == pytest.approx(expected, rel=0.03)  # 3 sigma of the estimate: 1.9 %
    # exact discretisation: one step of tau gives the same distribution
    one = gauss_markov_step(
        np.zeros(n), tau, np.full(n, tau), np.full(n, sigma), rng.standard_normal(n)
    )
    assert one.var() == pytest.approx(expected, rel=0.03)


def test_sensor_bias_drift_variance_across_seeds() -> None:
    # 2000 sensors x 6 axes at t = tau / 2 = 5 s: 12000 draws, estimate within 3.9 % (3 sigma)
    tau, sigma = 10.0, np.full(6, 0.05)
    biases = []
    for seed in range(2000):
        sensor = OdometrySensor(SensorConfig(bias_std=sigma, bias_tau_s=np.full(6, tau), seed=seed))
        for k in range(6):
            sensor.step(k * 1.0, X)
        biases.append(sensor.bias)
    var = np.array(biases).var()
    assert var == pytest.approx(0.05**2 * (1 - math.exp(-2 * 5.0 / tau)), rel=0.05)


def test_bias_drifts_slowly_and_adds_to_the_measurement() -> None:
    cfg = SensorConfig(bias_std=np.full(6, 0.1), bias_tau_s=np.full(6, 50.0), seed=2)
    sensor = OdometrySensor(cfg)
    prev, steps = None, []
    for k in range(500):
        [s] = sensor.step(k * 0.1, X)
        y = np.concatenate([s.eta, s.nu])
        np.testing.assert_allclose(y, X + sensor.bias, atol=1e-12)
        if prev is not None:
            steps.append(sensor.bias - prev)
        prev = sensor.bias
    # per step of 0.1 s the bias moves by sigma sqrt(1 - exp(-2 h / tau)) ~ 0.0063
    assert np.std(steps) == pytest.approx(0.1 * math.sqrt(1 - math.exp(-0.2 / 50)), rel=0.05)


def test_rate_decimates_the_truth_steps() -> None:
    samples = collect(SensorConfig(rate_hz=10.0), 1000, 0.01)  # 10 s of truth at 100 Hz
    times = np.array([s.t_measured_s for s in samples])
    assert len(samples) == 100
    np.testing.assert_allclose(np.diff(times), 0.1, atol=1e-9)


def test_rate_that_does_not_divide_the_step_keeps_its_mean() -> None:
    samples = collect(SensorConfig(rate_hz=3.0), 10_000, 0.02)  # 200 s at 50 Hz
    assert len(samples) == pytest.approx(600, abs=1)
    gaps = np.diff([s.t_measured_s for s in samples])
    assert set(np.round(gaps, 9)) <= {0.32, 0.34}


def test_delay_delivers_later_with_the_true_measurement_time() -> None:
    sensor = OdometrySensor(SensorConfig(delay_s=0.05))
    delivered: dict[int, list[Measurement]] = {}
    for k in range(20):
        delivered[k] = sensor.step(k * 0.01, X + k)
    assert all(delivered[k] == [] for k in range(5))
    for k in range(5, 20):
        [s] = delivered[k]
        assert s.t_measured_s == pytest.approx((k - 5) * 0.01)
        assert s.t_delivered_s == pytest.approx(k * 0.01)
        assert s.eta[0] == X[0] + k - 5  # the state at measurement time


def test_dropout_rate() -> None:
    n, p = 20_000, 0.2
    sensor = OdometrySensor(SensorConfig(dropout_p=p, seed=4))
    kept = sum(len(sensor.step(k * 0.02, X)) for k in range(n))
    assert sensor.sent == n and sensor.lost == n - kept
    assert sensor.lost / n == pytest.approx(p, abs=3 * math.sqrt(p * (1 - p) / n))


def test_outages_lose_the_expected_fraction_in_bursts() -> None:
    rate, mean = 0.1, 2.0  # one outage every 10 s on average, 2 s long
    sensor = OdometrySensor(SensorConfig(outage_rate_hz=rate, outage_mean_s=mean, seed=9))
    kept = [bool(sensor.step(k * 0.5, X)) for k in range(40_000)]  # 20000 s at 2 Hz
    lost = 1.0 - np.mean(kept)
    assert lost == pytest.approx(mean / (1 / rate + mean), abs=0.02)  # 0.167
    runs = np.diff(np.flatnonzero(np.diff(np.r_[1, kept, 1])))[::2]  # lengths of loss runs
    assert np.mean(runs) > 3.0  # bursts of ~4 samples (2 s at 2 Hz), not single losses


def test_same_seed_same_samples_other_seed_differs() -> None:
    cfg = SensorConfig(noise_std=STD, bias_std=STD, dropout_p=0.1, delay_s=0.04, seed=11)
    a, b = collect(cfg, 500, 0.02), collect(cfg, 500, 0.02)
    assert len(a) == len(b)
    np.testing.assert_array_equal(stacked(a), stacked(b))
    c = collect(SensorConfig(noise_std=STD, bias_std=STD, dropout_p=0.1, delay_s=0.04), 500, 0.02)
    assert len(c) != len(a) or not np.array_equal(stacked(c), stacked(a))


def test_dropouts_do_not_change_the_noise_of_kept_samples() -> None:
    clean = collect(SensorConfig(noise_std=STD, seed=3), 1000, 0.02)
    lossy = collect(SensorConfig(noise_std=STD, dropout_p=0.3, seed=3), 1000, 0.02)
    by_time = {s.t_measured_s: s for s in clean}
    assert len(lossy) < 800
    for s in lossy:
        np.testing.assert_array_equal(s.eta, by_time[s.t_measured_s].eta)


@pytest.mark.parametrize(
    ("kw", "word"),
    [
        ({"noise_std": [0.1, -0.1, 0, 0, 0, 0]}, "noise_std"),
        ({"rate_hz": 0.0}, "rate_hz"),
        ({"dropout_p": 1.5}, "dropout_p"),
        ({"delay_s": -0.1}, "delay_s"),
        ({"outage_rate_hz": 0.1}, "outage_mean_s"),
        ({"bias_std": np.ones(6), "bias_tau_s": np.zeros(6)}, "bias_tau_s"),
    ],
)
def test_bad_config_names_the_field(kw: dict[str, object], word: str) -> None:
    with pytest.raises(ValueError, match=word):
        SensorConfig(**kw)  # type: ignore[arg-type]
