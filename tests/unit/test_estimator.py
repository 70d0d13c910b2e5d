"""Fault estimators on synthetic, noise-free data w = B (delta * u + f)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ftcap_hil.core.effectiveness.geometry import ThrusterSet, effectiveness, paper_four_thrusters
from ftcap_hil.core.estimation.config import EstimatorConfig, wrench_scale
from ftcap_hil.core.estimation.windowed import LiteralEstimator, WindowedEstimator
from tests.support.vessels import six_thrusters

VESSELS = {"paper4": paper_four_thrusters, "six": six_thrusters}


def setup(name: str) -> tuple[ThrusterSet, np.ndarray, np.ndarray]:
    ths = VESSELS[name]()
    B = effectiveness(ths)
    return ths, B, wrench_scale(B, ths.u_min, ths.u_max)


def exciting(rng: np.random.Generator, ths: ThrusterSet) -> np.ndarray:
    return rng.uniform(ths.u_min, ths.u_max)


@pytest.mark.parametrize("name", sorted(VESSELS))
def test_windowed_converges_to_truth(name: str) -> None:
    ths, B, scale = setup(name)
    rng = np.random.default_rng(11)
    delta = rng.uniform(0.3, 1.0, ths.m)
    f = np.zeros(ths.m)
    f[0] = 0.1 * ths.u_max[0]
    est = WindowedEstimator(B, scale)
    for _ in range(80):
        u = exciting(rng, ths)
        e = est.update(u, B @ (delta * u + f))
    np.testing.assert_allclose(e.delta_hat, delta, rtol=0, atol=1e-3)
    np.testing.assert_allclose(e.bf_hat, B @ f, rtol=0, atol=1e-6 * scale.max())
    np.testing.assert_allclose(e.f_hat, np.linalg.pinv(B) @ (B @ f), rtol=0, atol=1e-6)
    assert e.window_len == est.config.window
    assert e.innovation < 1e-9


def test_held_thruster_stays_at_prior_but_wrench_is_predicted() -> None:
    """u_1 constant: delta_1 u_1 looks like a bias, so delta_1 is unidentifiable. It must not
    wander towards the (true, unobservable) 0.5; the bias absorbs the difference instead."""
    ths, B, scale = setup("paper4")
    rng = np.random.default_rng(5)
    delta = np.array([0.5, 1.0, 1.0, 0.8])
    f = np.array([0.01, 0.0, 0.0, 0.0])
    est = WindowedEstimator(B, scale)
    history = []
    for _ in range(400):
        u = exciting(rng, ths)
        u[0] = 0.05
        w = B @ (delta * u + f)
        pred = B @ (est.theta[:4] * u) + est.theta[4:]
        e = est.update(u, w)
        history.append((e.delta_hat.copy(), np.abs((w - pred) / scale).max()))
    d_late, err_late = history[-1]
    assert abs(d_late[0] - 1.0) < 0.02  # at the prior, not at 0.5
    later = np.array([d[0] for d, _ in history[50:]])
    assert np.ptp(later) < 1e-6  # and it does not drift over 350 further cycles
    np.testing.assert_allclose(d_late[1:], delta[1:], atol=1e-3)  # the others are identified
    assert err_late < 1e-9  # the wrench is still predicted
    # The held thruster's share is in the bias: delta_hat_1 * 0.05 B_1 + b = 0.5 * 0.05 B_1 + B f.
    expected_b = B[:, 0] * 0.05 * (delta[0] - d_late[0]) + B @ f
    np.testing.assert_allclose(est.theta[4:], expected_b, atol=1e-9)


def test_window_restarts_at_fault_onset() -> None:
    ths, B, scale = setup("paper4")
    rng = np.random.default_rng(2)
    est = WindowedEstimator(B, scale)
    healthy = np.ones(4)
    faulty = np.array([1.0, 0.6, 1.0, 1.0])
    restarts = []
    for t in range(120):
        delta = healthy if t < 40 else faulty
        u = exciting(rng, ths)
        e = est.update(u, B @ (delta * u))
        if e.restarted:
            restarts.append(t)
            assert e.window_len == 1
    assert restarts and restarts[0] == 40
    assert all(t < 40 + est.config.window for t in restarts)  # no restarts once settled
    np.testing.assert_allclose(e.delta_hat, faulty, atol=1e-3)
    assert e.window_len == est.config.window


def test_dead_thruster_identified_and_recovers() -> None:
    ths, B, scale = setup("paper4")
    rng = np.random.default_rng(9)
    est = WindowedEstimator(B, scale)
    # Phase 1: thruster 3 produces nothing while commanded.
    for _ in range(60):
        u = exciting(rng, ths)
        e = est.update(u, B @ (np.array([1.0, 1.0, 0.0, 1.0]) * u))
    assert abs(e.delta_hat[2]) < 1e-3
    # Phase 2: it recovered, but is taken out (command 0): no evidence, the estimate holds.
    for _ in range(60):
        u = exciting(rng, ths)
        u[2] = 0.0
        e = est.update(u, B @ u)
    assert abs(e.delta_hat[2]) < 1e-3
    # Phase 3: its command varies again (e.g. recovery probes): back to 1.
    for _ in range(60):
        u = exciting(rng, ths)
        e = est.update(u, B @ u)
    assert abs(e.delta_hat[2] - 1.0) < 1e-3
    np.testing.assert_allclose(e.delta_hat, np.ones(4), atol=1e-3)


def test_reset_sets_prior() -> None:
    _ths, B, scale = setup("paper4")
    est = WindowedEstimator(B, scale)
    est.reset(delta=np.array([0.2, 0.4, 0.6, 0.8]), bf=np.array([0.1, 0.2, 0.3]))
    e = est.estimate()
    np.testing.assert_array_equal(e.delta_hat, [0.2, 0.4, 0.6, 0.8])
    np.testing.assert_array_equal(e.bf_hat, [0.1, 0.2, 0.3])
    assert e.window_len == 0


def test_delta_estimate_is_bounded() -> None:
    """Data that would need delta > 1 (or < 0) is clipped to [0, 1]."""
    ths, B, scale = setup("paper4")
    rng = np.random.default_rng(4)
    est = WindowedEstimator(B, scale)
    for _ in range(40):
        u = exciting(rng, ths)
        e = est.update(u, B @ (np.array([1.5, -0.5, 1.0, 1.0]) * u))
    assert np.all(e.delta_hat >= 0.0) and np.all(e.delta_hat <= 1.0)
    assert e.delta_hat[0] == pytest.approx(1.0, abs=1e-6)
    assert e.delta_hat[1] == pytest.approx(0.0, abs=1e-6)


def test_prefilter_changes_nothing_on_noise_free_data() -> None:
    """Filtering command and wrench alike keeps a noise-free sample exact, and the filter
    restarts with the window (and again after the straddling sample is evicted), so the
    estimates match the unfiltered ones through a fault onset."""
    ths, B, scale = setup("paper4")
    rng = np.random.default_rng(4)
    plain = WindowedEstimator(B, scale)
    filtered = WindowedEstimator(B, scale, EstimatorConfig(prefilter=0.5))
    f = np.array([0.0, 0.005, 0.0, 0.0])
    for t in range(120):
        delta = np.ones(4) if t < 40 else np.array([1.0, 0.6, 1.0, 0.0])
        u = exciting(rng, ths)
        w = B @ (delta * u + f)
        a, b = plain.update(u, w), filtered.update(u, w)
        assert a.restarted == b.restarted
        assert a.window_len == b.window_len
        if a.window_len >= 4:  # fewer samples than unknowns: the minimum change decides
            np.testing.assert_allclose(b.delta_hat, a.delta_hat, atol=1e-6)
            np.testing.assert_allclose(b.bf_hat, a.bf_hat, atol=1e-6 * scale.max())
    np.testing.assert_allclose(b.delta_hat, delta, atol=1e-3)


def test_prefilter_averages_the_fitted_samples() -> None:
    """The fit sees (1 - a) / (1 - a q^-1) of the command: with a = 0.5 and u = 1, 0, 0 the
    fitted commands are 1, 0.5, 0.25 (visible in the window's normal equations)."""
    ths, B, scale = setup("paper4")
    est = WindowedEstimator(B, scale, EstimatorConfig(prefilter=0.5, change_floor=1e9))
    for u1 in (0.1, 0.0, 0.0):
        est.update(np.array([u1, 0.0, 0.0, 0.0]), B @ np.array([u1, 0.0, 0.0, 0.0]))
    # H[0, 0] = sum_j (S^-1 B_1 u_1j)^2 over the three fitted samples
    b1 = np.sum((B[:, 0] / scale) ** 2)
    assert est._H[0, 0] == pytest.approx(b1 * (0.1**2 + 0.05**2 + 0.025**2), rel=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        ({"window": 1}, "window"),
        ({"change_floor": 0.0}, "change_floor"),
        ({"prior_weight_delta": -1.0}, "prior_weight_delta"),
        ({"prefilter": 1.0}, "prefilter"),
        ({"prefilter": -0.1}, "prefilter"),
    ],
)
def test_config_errors_name_key(kwargs: dict[str, float], key: str) -> None:
    with pytest.raises(ValueError, match=key):
        EstimatorConfig(**kwargs)


vec4 = st.lists(st.floats(-0.1, 0.1), min_size=4, max_size=4).map(np.array)
vec3 = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).map(np.array)


@settings(max_examples=60, deadline=None)
@given(samples=st.lists(st.tuples(vec4, vec3), min_size=1, max_size=40))
def test_literal_estimator_never_leaves_prior(samples: list[tuple[np.ndarray, np.ndarray]]) -> None:
    """Pinned paper finding: eq. (9) puts the whole residual into the bias, so eq. (11) sees a
    zero slack and Delta_hat stays at its initial value whatever the data."""
    _ths, B, scale = setup("paper4")
    est = LiteralEstimator(B, scale)
    for u, w in samples:
        e = est.update(u, w)
        np.testing.assert_array_equal(e.delta_hat, np.ones(4))
        np.testing.assert_array_equal(e.bf_hat, w - B @ u)
        np.testing.assert_allclose(e.f_hat, np.linalg.pinv(B) @ (w - B @ u), atol=1e-12)
    assert e.window_len == min(len(samples), est.config.window)
