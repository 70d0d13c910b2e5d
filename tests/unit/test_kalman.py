"""The Kalman fault estimator (core/estimation/kalman.py) and its decisions
(core/estimation/decisions.py), open loop on the paper vessel with known commands and a
known truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ftcap_hil.core.effectiveness.geometry import effectiveness, paper_four_thrusters
from ftcap_hil.core.estimation.config import EstimatorConfig, wrench_scale
from ftcap_hil.core.estimation.decisions import FaultDecider
from ftcap_hil.core.estimation.kalman import KalmanEstimator, VesselStep, step_model
from ftcap_hil.core.models.plants import Inversion, SurfaceVessel

THS = paper_four_thrusters()
B = effectiveness(THS)
S = wrench_scale(B, THS.u_min, THS.u_max)
PLANT = SurfaceVessel()
DT = 0.2827
RANGE = np.full(4, 0.1)


def drive(
    kf: KalmanEstimator,
    delta: np.ndarray,
    f: np.ndarray,
    n: int,
    rng: np.random.Generator,
    noise: float = 0.0,
    x0: np.ndarray | None = None,
    u_fixed: dict[int, float] | None = None,
) -> tuple[np.ndarray, list]:
    """n samples of the paper's discrete vessel (the filter's own model) under random
    commands; returns the last true state and the filter outputs."""
    x = np.zeros(6) if x0 is None else x0
    outs = []
    meas_prev = x.copy()
    for _ in range(n):
        u = rng.uniform(-0.1, 0.1, 4)
        for i, v in (u_fixed or {}).items():
            u[i] = v
        x = PLANT.step(x, B @ (delta * u + f), DT)
        meas = x.copy()
        meas[3:] += rng.normal(0.0, noise, 3) if noise else 0.0
        outs.append(kf.update(u, meas, DT, meas_prev))
        meas_prev = meas
    return x, outs


def test_a_weak_and_biased_thruster_is_identified_with_a_shrinking_variance() -> None:
    kf = KalmanEstimator(B, S, PLANT, EstimatorConfig())
    rng = np.random.default_rng(0)
    delta, f = np.array([1.0, 0.6, 1.0, 1.0]), np.array([0.0, 0.02, 0.0, 0.0])
    _, outs = drive(kf, delta, f, 60, rng)
    est = outs[-1].estimate
    np.testing.assert_allclose(est.delta_hat, delta, atol=0.01)
    np.testing.assert_allclose(est.bf_hat, B @ f, atol=2e-4)
    assert est.delta_std is not None and np.all(est.delta_std < 0.05)
    assert outs[-1].estimate.delta_std[1] < 0.1 * outs[0].estimate.delta_std[1]  # it learnt


def test_an_onset_raises_one_alarm_and_the_suspect_is_the_faulty_thruster() -> None:
    kf = KalmanEstimator(B, S, PLANT, EstimatorConfig(measurement_std=(1e-4,) * 3))
    rng = np.random.default_rng(1)
    x, before = drive(kf, np.ones(4), np.zeros(4), 40, rng, noise=1e-4)
    assert not any(o.alarm for o in before[5:])
    _, after = drive(kf, np.array([1.0, 1.0, 0.0, 1.0]), np.zeros(4), 30, rng, 1e-4, x)
    alarms = [i for i, o in enumerate(after) if o.alarm]
    assert len(alarms) == 1 and alarms[0] <= 2, alarms
    assert kf.suspects[2]
    assert after[-1].estimate.delta_hat[2] < 0.05
    healthy = np.array([o.estimate.delta_hat[[0, 1, 3]] for o in after])
    assert healthy.min() > 0.9  # the others were not made unknown by the alarm


def test_an_unexcited_thruster_keeps_its_estimate_and_grows_its_variance() -> None:
    kf = KalmanEstimator(B, S, PLANT, EstimatorConfig(measurement_std=(1e-3,) * 3))
    rng = np.random.default_rng(2)
    x, outs = drive(kf, np.ones(4), np.zeros(4), 40, rng, noise=1e-3)
    held = outs[-1].estimate
    _, idle = drive(kf, np.ones(4), np.zeros(4), 60, rng, 1e-3, x, u_fixed={0: 0.0})
    assert abs(idle[-1].estimate.delta_hat[0] - held.delta_hat[0]) < 0.05
    assert idle[-1].estimate.delta_std[0] > held.delta_std[0]
    assert idle[-1].info[0] == 0.0  # no information about an idle thruster


def test_delta_stays_in_its_bounds_while_commands_saturate() -> None:
    """A saturated thruster at 0.9 x 0.1 + 0.01 = 0.1 N looks healthy; the covariance-weighted
    projection keeps the estimates consistent (a plain clip made them drift away)."""
    kf = KalmanEstimator(B, S, PLANT, EstimatorConfig())
    rng = np.random.default_rng(3)
    sat = {0: 0.1, 1: 0.1, 2: -0.1, 3: -0.1}
    _, outs = drive(kf, np.array([0.9, 1, 1, 1]), np.array([0.01, 0, 0, 0]), 30, rng, u_fixed=sat)
    for o in outs:
        assert np.all((o.estimate.delta_hat >= 0.0) & (o.estimate.delta_hat <= 1.0))
    assert outs[-1].nis < 1.0  # predictions stay consistent with the data


def test_the_measurement_std_must_match_the_plant() -> None:
    with pytest.raises(ValueError, match="measurement_std"):
        KalmanEstimator(B, S, PLANT, EstimatorConfig(measurement_std=(1e-3, 1e-3)))


def test_the_vessel_step_jacobians_match_finite_differences() -> None:
    for inversion in Inversion:
        model = VesselStep(SurfaceVessel(inversion=inversion))
        s0, w = np.array([0.3, -0.1, 0.2]), np.array([0.05, -0.02, 0.01])
        s1, A, G = model.predict(s0, w, DT)
        for j in range(3):
            h = 1e-6
            ds = np.zeros(3)
            ds[j] = h
            np.testing.assert_allclose(
                (model.predict(s0 + ds, w, DT)[0] - s1) / h, A[:, j], atol=1e-4
            )
            np.testing.assert_allclose(
                (model.predict(s0, w + ds, DT)[0] - s1) / h, G[:, j], atol=1e-4
            )


def _decide(kf: KalmanEstimator, decider: FaultDecider, delta: np.ndarray, f: np.ndarray, n: int):
    rng = np.random.default_rng(4)
    x, meas_prev, dec = np.zeros(6), np.zeros(6), None
    for _ in range(n):
        u = rng.uniform(-0.1, 0.1, 4)
        x = PLANT.step(x, B @ (delta * u + f), DT)
        dec = decider.update(kf.update(u, x, DT, meas_prev), DT)
        meas_prev = x.copy()
    return dec


def test_a_dead_thruster_is_flagged_and_removed_a_healthy_one_is_left_alone() -> None:
    cfg = EstimatorConfig()
    kf = KalmanEstimator(B, S, PLANT, cfg)
    decider = FaultDecider(B, RANGE, cfg, 0.85, 0.95)
    dec = _decide(kf, decider, np.array([1.0, 1.0, 0.0, 1.0]), np.zeros(4), 40)
    assert dec is not None
    np.testing.assert_array_equal(dec.faulty, [False, False, True, False])
    np.testing.assert_array_equal(dec.removed, [False, False, True, False])
    np.testing.assert_array_equal(dec.delta_alloc, [1.0, 1.0, 0.0, 1.0])


def test_an_uncertain_loss_leaves_the_allocation_at_cap() -> None:
    """The allocator gets min(1, delta_hat + z_use sigma): a loss the data do not support
    leaves it at 1 (CAP's behaviour for that thruster); an established fault (its bound at
    z_flag below 0.85), the estimate itself."""
    cfg = EstimatorConfig()
    decider = FaultDecider(B, RANGE, cfg, 0.85, 0.95)
    kf = KalmanEstimator(B, S, PLANT, cfg)
    out = kf.update(np.zeros(4), np.zeros(6), DT, np.zeros(6))
    est = out.estimate
    unsure = dataclasses.replace(
        out, estimate=dataclasses.replace(est, delta_hat=np.array([0.8, 1, 1, 1])),
        delta_var=np.array([0.15**2, 1e-4, 1e-4, 1e-4]),
    )  # fmt: skip
    dec = decider.update(unsure, DT)
    assert dec.delta_alloc[0] == 1.0 and not dec.faulty[0]
    fairly = dataclasses.replace(unsure, delta_var=np.array([0.03**2, 1e-4, 1e-4, 1e-4]))
    dec = decider.update(fairly, DT)  # 0.8 + 4 x 0.03 = 0.92: not established
    assert dec.delta_alloc[0] == pytest.approx(0.86) and not dec.faulty[0]
    sure = dataclasses.replace(unsure, delta_var=np.array([0.01**2, 1e-4, 1e-4, 1e-4]))
    dec = decider.update(sure, DT)
    assert dec.delta_alloc[0] == pytest.approx(0.8) and dec.faulty[0]


def test_a_thruster_bias_is_attributed_an_environmental_offset_is_not() -> None:
    cfg = EstimatorConfig()
    # A 0.03 N bias along thruster 2's column, after a healthy start: attributed.
    kf = KalmanEstimator(B, S, PLANT, cfg)
    decider = FaultDecider(B, RANGE, cfg, 0.85, 0.95)
    _decide(kf, decider, np.ones(4), np.zeros(4), 30)
    dec = _decide(kf, decider, np.ones(4), np.array([0.0, 0.03, 0.0, 0.0]), 30)
    assert dec is not None and dec.bias_faulty[1] and not dec.bias_faulty[[0, 2, 3]].any()
    assert dec.f_alloc[1] == pytest.approx(0.03, abs=0.003)
    # A pure sway push of the same size (a current, a wind) lies along no single thruster.
    kf = KalmanEstimator(B, S, PLANT, cfg)
    decider = FaultDecider(B, RANGE, cfg, 0.85, 0.95)
    _decide(kf, decider, np.ones(4), np.zeros(4), 30)
    f_env = np.linalg.pinv(B) @ np.array([0.0, 0.03, 0.0])  # B f_env = [0, 0.03, 0]
    dec = _decide(kf, decider, np.ones(4), f_env, 30)
    assert dec is not None and not dec.bias_faulty.any()
    np.testing.assert_array_equal(dec.bf_alloc, np.zeros(3))


# --- the pose step and the wave model (realistic scenarios) ---------------------------


@pytest.mark.parametrize("preset", ["cybership2", "supply"])
@pytest.mark.parametrize("dt", [0.1, 0.5, 2.0])
def test_pose_step_jacobians_match_finite_differences(preset: str, dt: float) -> None:
    from ftcap_hil.config.presets import load_preset
    from ftcap_hil.core.estimation.step_models import PoseStep

    vessel = dataclasses.replace(load_preset(preset).vessel, inversion=Inversion.TRAPEZOID)
    step = PoseStep(vessel)
    scale = 1e5 if preset == "supply" else 1.0
    s0 = np.array([1.0, 2.0, 0.7, 0.3, -0.1, 0.05])
    w = np.array([0.8, -0.5, 0.3]) * scale
    _s1, A, G = step.predict(s0, w, dt)
    num_a = np.column_stack([
        (step.predict(s0 + d, w, dt)[0] - step.predict(s0 - d, w, dt)[0]) / 2e-6
        for d in np.eye(6) * 1e-6
    ])  # fmt: skip
    num_g = np.column_stack([
        (step.predict(s0, w + d, dt)[0] - step.predict(s0, w - d, dt)[0]) / (2e-6 * scale)
        for d in np.eye(3) * 1e-6 * scale
    ])  # fmt: skip
    np.testing.assert_allclose(A, num_a, atol=1e-5)
    np.testing.assert_allclose(G, num_g, rtol=1e-4, atol=1e-6 * np.abs(num_g).max())


def test_pose_innovation_wraps_the_heading() -> None:
    from ftcap_hil.core.estimation.step_models import PoseStep

    e = PoseStep(SurfaceVessel()).innovation(np.array([0, 0, -3.1, 0, 0, 0.0]),
                                            np.array([0, 0, 3.1, 0, 0, 0.0]))  # fmt: skip
    assert e[2] == pytest.approx(2 * np.pi - 6.2)


def test_wave_model_is_stationary_at_the_told_level() -> None:
    from ftcap_hil.core.estimation.wave_model import WaveModel

    sigma = np.array([2.0, 3.0, 0.5])
    model = WaveModel(2 * np.pi / 8.0, 0.1, sigma)
    for dt in (0.1, 0.5, 2.0):
        st = model.step(dt)
        P = model.stationary_cov()
        # the discrete model keeps the stationary covariance: Phi P Phi^T + Qd = P
        np.testing.assert_allclose(st.phi @ P @ st.phi.T + st.q, P, rtol=1e-9, atol=1e-12)
        assert model.step(dt) is st  # cached
    # over a short interval the mean force is the force at its start
    np.testing.assert_allclose(model.step(1e-6).mean[0, :2], [0.0, 1.0], atol=1e-5)


def test_wave_states_explain_an_oscillating_load() -> None:
    """A vessel pushed by a 0.5 rad/s sinusoid the size of its thrusters, thrusters
    healthy: with the wave states the effectiveness stays at 1 and nothing alarms;
    without, the load is taken for a change."""
    plant = SurfaceVessel()
    B = effectiveness(paper_four_thrusters(0.3))
    scale = np.abs(B) @ np.full(4, 0.1)
    std = (1e-4, 1e-4, 1e-4)
    rng = np.random.default_rng(1)
    for waves in (True, False):
        cfg = EstimatorConfig(
            measurement_std=std,
            wave_period_s=2 * np.pi / 0.5 if waves else 0.0,
            wave_force_std=tuple(0.7 * scale) if waves else None,
        )
        kf = KalmanEstimator(B, scale, plant, cfg)
        step = step_model(plant)
        nu = np.zeros(3)
        alarms, low = 0, 1.0
        kf.update(np.zeros(4), np.concatenate([np.zeros(3), nu]), 0.28, np.zeros(6))
        for k in range(400):
            u = 0.05 * rng.choice([-1.0, 1.0], 4)
            load = scale * np.sin(0.5 * 0.28 * k)
            nu, _A, _G = step.predict(nu, B @ u + load, 0.28)
            out = kf.update(u, np.concatenate([np.zeros(3), nu + rng.normal(0, 1e-4, 3)]), 0.28)
            alarms += out.alarm
            low = min(low, float(out.estimate.delta_hat.min()))
        if waves:
            assert alarms == 0 and low > 0.9, (alarms, low)
        else:
            assert alarms > 0 or low < 0.9, (alarms, low)


def test_damping_error_states_keep_a_moving_vessel_healthy() -> None:
    """CyberShip II whose true damping is 30 % below the model, driven through speed changes
    with healthy thrusters: without damping-error states the missing damping reads as lost
    effectiveness; with them delta-hat stays up and theta finds the error."""
    from ftcap_hil.config.presets import load_preset

    preset = load_preset("cybership2")
    model = dataclasses.replace(preset.vessel, inversion=Inversion.TRAPEZOID)
    truth = model.scaled(damping=0.7)
    B, ths = preset.B, preset.thrusters
    scale = wrench_scale(B, ths.u_min, ths.u_max)
    std = (2e-3, 2e-3, 2e-3)
    lows, thetas = {}, {}
    for states in (True, False):
        rng = np.random.default_rng(3)
        cfg = EstimatorConfig(measurement_std=std, damping_error_std=0.5 if states else 0.0)
        kf = KalmanEstimator(B, scale, model, cfg)
        step = step_model(truth)
        nu = np.zeros(3)
        kf.update(np.zeros(5), np.zeros(6), 0.1, np.zeros(6))
        low, dt = 1.0, 0.1
        for k in range(3000):
            surge = 2.0 + 1.5 * np.sin(2 * np.pi * k * dt / 60.0)  # mains: speed changes
            u = np.array([surge, surge, 0.0, 0.0, 0.0]) + rng.uniform(-0.3, 0.3, 5) * [
                3, 3, 1, 1, 0.15]  # fmt: skip
            nu, _A, _G = step.predict(nu, B @ u, dt)
            out = kf.update(u, np.concatenate([np.zeros(3), nu + rng.normal(0, 2e-3, 3)]), dt)
            if k > 600:
                low = min(low, float(out.estimate.delta_hat.min()))
        lows[states], thetas[states] = low, kf.z[kf._d0 :].copy()
    assert lows[True] > 0.9, lows
    assert lows[False] < 0.85, lows  # the case the states are for
    assert thetas[True][0] == pytest.approx(-0.3, abs=0.1), thetas  # surge, the axis driven


def test_damping_error_states_need_a_vessel_model() -> None:
    with pytest.raises(ValueError, match="damping_error_std"):
        KalmanEstimator(B, S, PLANT, EstimatorConfig(damping_error_std=0.5))
