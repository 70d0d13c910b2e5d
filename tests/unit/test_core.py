"""FtcapCore per mode on the paper vessel, with synthetic measured wrenches (the windowed
estimator works on wrenches; the Kalman estimator's own tests are in test_kalman.py)."""

from __future__ import annotations

import numpy as np
import pytest

from ftcap_hil.core.allocation.allocator import AllocationStatus
from ftcap_hil.core.cycle import CoreConfig, FtcapCore
from ftcap_hil.core.effectiveness.geometry import (
    command_bounds,
    effectiveness,
    paper_four_thrusters,
)
from ftcap_hil.core.estimation.config import EstimatorConfig, EstimatorKind
from ftcap_hil.core.evidence import Evidence
from ftcap_hil.core.faults import Truth
from ftcap_hil.core.status import Mode

THS = paper_four_thrusters()
B = effectiveness(THS)
DT_S = 0.2827
TRUTH = Truth(np.array([0.7, 1.0, 1.0, 0.9]), np.array([0.0, 0.005, 0.0, 0.0]))
TAU_D = np.array([0.05, 0.02, 0.005])


WINDOWED = EstimatorConfig(kind=EstimatorKind.WINDOWED)


def make(mode: Mode) -> FtcapCore:
    return FtcapCore(B, THS, DT_S, CoreConfig(mode=mode, estimator=WINDOWED))


def run(core: FtcapCore, cycles: int, truth: Truth = TRUTH) -> list:
    """Closed loop with the plant replaced by w = B (delta u + f) of the applied command."""
    results, w = [], None
    for _ in range(cycles):
        u_prev = core.u_prev.copy()
        r = core.step(TAU_D, w, truth=truth)
        lo, hi = command_bounds(THS.u_min, THS.u_max, THS.max_step(DT_S), u_prev)
        assert np.all(lo <= r.u) and np.all(r.u <= hi)
        w = B @ (truth.delta * r.u + truth.f)
        results.append(r)
    return results


def test_oracle_uses_truth() -> None:
    core = make(Mode.ORACLE)
    r = core.step(TAU_D, None, truth=TRUTH)
    np.testing.assert_array_equal(r.estimate.delta_hat, TRUTH.delta)
    np.testing.assert_allclose(r.estimate.bf_hat, B @ TRUTH.f, atol=1e-15)
    np.testing.assert_array_equal(r.estimate.f_hat, TRUTH.f)
    np.testing.assert_array_equal(r.faulty, [True, False, False, False])
    assert not r.estimation_frozen
    # The oracle's plan is the real wrench, and it meets the demand after a few cycles.
    last = run(core, 10)[-1]
    np.testing.assert_allclose(
        last.allocation.tau_planned, B @ (TRUTH.delta * last.u + TRUTH.f), atol=1e-15
    )
    assert np.max(np.abs(last.allocation.unallocated)) < 1e-6


def test_oracle_estimate_is_a_copy() -> None:
    core = make(Mode.ORACLE)
    delta = TRUTH.delta.copy()
    r = core.step(TAU_D, None, truth=Truth(delta, TRUTH.f.copy()))
    delta[0] = 0.0
    assert r.estimate.delta_hat[0] == 0.7


def test_oracle_without_truth_raises() -> None:
    with pytest.raises(ValueError, match="oracle"):
        make(Mode.ORACLE).step(TAU_D, np.zeros(3))


@pytest.mark.parametrize("mode", [Mode.CAP, Mode.NONE])
def test_cap_keeps_identity(mode: Mode) -> None:
    results = run(make(mode), 60)
    for r in results:
        np.testing.assert_array_equal(r.estimate.delta_hat, np.ones(4))
        np.testing.assert_array_equal(r.estimate.bf_hat, np.zeros(3))
        assert not r.faulty.any() and not r.probing.any()
        assert not r.estimation_frozen
    # Blind to the fault, CAP plans the demand but the faulty vessel misses it.
    last = results[-1]
    np.testing.assert_allclose(last.allocation.tau_planned, TAU_D, atol=1e-6)
    assert np.max(np.abs(B @ (TRUTH.delta * last.u + TRUTH.f) - TAU_D)) > 1e-3


def test_ftcap_identifies_faults_and_meets_demand() -> None:
    results = run(make(Mode.FTCAP), 150)
    last = results[-1]
    np.testing.assert_allclose(last.estimate.delta_hat, TRUTH.delta, atol=1e-3)
    np.testing.assert_allclose(last.estimate.bf_hat, B @ TRUTH.f, atol=1e-6)
    np.testing.assert_array_equal(last.faulty, [True, False, False, False])  # 0.9 >= 0.8
    assert last.allocation.status is AllocationStatus.OK
    produced = B @ (TRUTH.delta * last.u + TRUTH.f)
    assert np.max(np.abs(produced - TAU_D)) < 1e-5


def test_literal_mode_keeps_delta_at_one() -> None:
    results = run(make(Mode.FTCAP_LITERAL), 60)
    np.testing.assert_array_equal(results[-1].estimate.delta_hat, np.ones(4))


@pytest.mark.parametrize("mode", [Mode.FTCAP, Mode.FTCAP_LITERAL])
def test_stale_telemetry_freezes_estimate(mode: Mode) -> None:
    core = make(mode)
    before = run(core, 30)[-1].estimate
    for _ in range(5):
        r = core.step(TAU_D, None)
        assert r.estimation_frozen
        np.testing.assert_array_equal(r.estimate.delta_hat, before.delta_hat)
        np.testing.assert_array_equal(r.estimate.bf_hat, before.bf_hat)
        assert np.all(np.isfinite(r.u))
    # Fresh telemetry resumes estimation.
    r = core.step(TAU_D, B @ (TRUTH.delta * core.u_prev + TRUTH.f))
    assert not r.estimation_frozen


def test_cap_stale_telemetry_is_not_frozen_estimation() -> None:
    r = make(Mode.CAP).step(TAU_D, None)
    assert not r.estimation_frozen


def test_non_finite_telemetry_reports_frozen() -> None:
    core = make(Mode.FTCAP)
    before = run(core, 30)[-1].estimate
    r = core.step(TAU_D, np.array([np.nan, 0.0, 0.0]))
    np.testing.assert_array_equal(r.estimate.delta_hat, before.delta_hat)  # frozen: holds
    assert r.estimation_frozen


def test_u_sample_feeds_the_estimator_not_the_rate_box() -> None:
    core = make(Mode.FTCAP_LITERAL)
    core.reset_command(np.array([0.05, 0.05, -0.05, -0.05]))
    u_sample = np.array([0.01, -0.02, 0.03, 0.0])
    w = np.array([0.02, -0.01, 0.003])
    r = core.step(TAU_D, w, u_sample=u_sample)
    # The literal estimator's bias is the whole residual of the sample it was given.
    np.testing.assert_array_equal(r.estimate.bf_hat, w - B @ u_sample)
    # The rate box is centred on the command now on the actuators.
    lo, hi = command_bounds(
        THS.u_min, THS.u_max, THS.max_step(DT_S), np.array([0.05, 0.05, -0.05, -0.05])
    )
    assert np.all(lo <= r.u) and np.all(r.u <= hi)


def test_forced_dead_takes_thruster_out_for_that_cycle_only() -> None:
    core = make(Mode.FTCAP)
    run(core, 20, truth=Truth(np.ones(4), np.zeros(4)))
    core.reset_command(np.array([0.08, 0.0, 0.0, 0.0]))
    forced = np.array([True, False, False, False])
    r = core.step(TAU_D, None, evidence=Evidence.of(4, dead=forced))
    assert r.estimate.delta_hat[0] == 0.0
    assert r.allocation.dead[0] and r.faulty[0]
    assert r.u[0] == pytest.approx(0.0, abs=1e-15)  # 0.08 is within one step (0.09) of 0
    r = core.step(TAU_D, None)
    assert r.estimate.delta_hat[0] == pytest.approx(1.0, abs=1e-3)  # the estimator kept it
    assert not r.allocation.dead[0]


def test_evidence_counts_a_dead_and_stalled_thruster_as_dead() -> None:
    ev = Evidence.of(4, dead=[True, False, False, False], stalled=[True, True, False, False])
    assert ev.dead.tolist() == [True, False, False, False]
    assert ev.stalled.tolist() == [False, True, False, False]
    assert ev.out.tolist() == [True, True, False, False]
    assert not Evidence.none(4).out.any()


def test_evidence_of_the_wrong_length_is_refused() -> None:
    with pytest.raises(ValueError, match=r"evidence.stalled: expected 4 flags"):
        Evidence.of(4, stalled=[True, False])


def test_elapsed_s_sets_the_rate_box() -> None:
    ths = paper_four_thrusters(rate_limit=0.5)
    core = FtcapCore(effectiveness(ths), ths, 0.1, CoreConfig(mode=Mode.CAP))
    far = np.array([10.0, 0.0, 0.0])  # saturating surge demand
    r = core.step(far, None, elapsed_s=0.1)
    np.testing.assert_allclose(np.abs(r.u), 0.05, atol=1e-9)  # 0.5 N/s * 0.1 s
    r = core.step(far, None, elapsed_s=0.04)
    np.testing.assert_allclose(np.abs(r.u), 0.07, atol=1e-9)  # + 0.5 N/s * 0.04 s


def test_reset_command() -> None:
    core = make(Mode.CAP)
    run(core, 5)
    core.reset_command()
    np.testing.assert_array_equal(core.u_prev, np.zeros(4))
    core.reset_command(np.array([0.1, 0.0, 0.0, -0.1]))
    np.testing.assert_array_equal(core.u_prev, [0.1, 0.0, 0.0, -0.1])


def test_column_count_mismatch_raises() -> None:
    with pytest.raises(ValueError, match="4 thrusters"):
        FtcapCore(B[:, :3], THS, DT_S)


def test_elapsed_s_default_is_the_configured_period() -> None:
    ths = paper_four_thrusters(rate_limit=0.5)
    core = FtcapCore(effectiveness(ths), ths, 0.1, CoreConfig(mode=Mode.CAP))
    far = np.array([10.0, 0.0, 0.0])
    core.step(far, None, elapsed_s=0.02)  # one short cycle: |u| = 0.01
    r = core.step(far, None)  # default: the configured 0.1 s, so |u| = 0.01 + 0.05
    np.testing.assert_allclose(np.abs(r.u), 0.06, atol=1e-9)


def test_constant_demand_ramps_to_optimum_with_default_backend() -> None:
    ths = paper_four_thrusters(rate_limit=0.318359)  # the HIL config: 0.09 N per T_s
    Bp = effectiveness(ths)
    tau_d = np.array([0.2, 0.05, 0.01])  # reachable, but only after several rate steps
    core = FtcapCore(Bp, ths, 0.01, CoreConfig(mode=Mode.CAP))  # default backend: proxqp
    for _ in range(60):
        r = core.step(tau_d, None)
    np.testing.assert_allclose(Bp @ r.u, tau_d, atol=1e-5)
