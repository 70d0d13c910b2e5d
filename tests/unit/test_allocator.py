"""Allocator invariants: bounds always hold, a dead thruster gets nothing, a feasible demand
is met, bad input and solver failure are data, and the QP backends agree."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ftcap_hil.core.allocation.allocator import AllocationStatus, Allocator, AllocatorConfig
from ftcap_hil.core.allocation.qp import BoxQpSolution, available_backends
from ftcap_hil.core.effectiveness.geometry import (
    ThrusterSet,
    command_bounds,
    effectiveness,
    paper_four_thrusters,
)
from ftcap_hil.core.estimation.config import wrench_scale
from tests.support.vessels import six_thrusters

DT_S = 0.1
VESSELS = {"paper4": paper_four_thrusters, "six": six_thrusters}
BACKENDS = ["proxqp", "daqp"]


@functools.cache
def vessel(name: str) -> tuple[ThrusterSet, np.ndarray, np.ndarray]:
    ths = VESSELS[name]()
    B = effectiveness(ths)
    return ths, B, wrench_scale(B, ths.u_min, ths.u_max)


@functools.cache
def shared_allocator(name: str, backend: str) -> Allocator:
    """One allocator per (vessel, backend), reused across examples as in the real loop, so
    the warm start is exercised too."""
    return fresh_allocator(name, backend)


def fresh_allocator(name: str, backend: str) -> Allocator:
    ths, B, scale = vessel(name)
    return Allocator(B, ths, DT_S, scale, AllocatorConfig(backend=backend))


def unit_floats(n: int) -> st.SearchStrategy[np.ndarray]:
    return st.lists(st.floats(0.0, 1.0), min_size=n, max_size=n).map(np.array)


# proxqp needs up to 300200 inner iterations (seconds) on demands beyond ~1e10 x scale (see
# test_proxqp_iteration_budget_on_huge_demand), so its random demands stop at 1e8 x scale and
# the huge ones are covered by a few fixed cases; daqp gets the full range.
MAX_EXPONENT = {"proxqp": 8.0, "daqp": 300.0}


@st.composite
def demand(draw: st.DrawFn, scale: np.ndarray, max_exponent: float) -> np.ndarray:
    """Per axis: a multiple of the axis scale from 1e-300 to 1e(max_exponent), or zero."""
    out = np.empty(scale.size)
    for j in range(scale.size):
        exponent = draw(st.one_of(st.floats(-1.0, 1.0), st.floats(-300.0, max_exponent)))
        sign = draw(st.sampled_from([-1.0, 0.0, 1.0]))
        out[j] = sign * scale[j] * 10.0**exponent
    return out


@st.composite
def problem(draw: st.DrawFn, name: str, max_exponent: float) -> tuple[np.ndarray, ...]:
    ths, _B, scale = vessel(name)
    m = ths.m
    tau_d = draw(demand(scale, max_exponent))
    delta_hat = draw(st.one_of(unit_floats(m), unit_floats(m).map(lambda d: np.round(d, 1))))
    bf_hat = (draw(unit_floats(3)) * 2.0 - 1.0) * scale * 0.5
    frac = draw(unit_floats(m))
    u_prev = ths.u_min + frac * (ths.u_max - ths.u_min)
    u_prev = np.where(draw(unit_floats(m)) < 0.2, 0.0, u_prev)  # often exactly at rest
    return tau_d, delta_hat, bf_hat, u_prev


def check_invariants(
    alloc_obj: Allocator,
    name: str,
    tau_d: np.ndarray,
    delta_hat: np.ndarray,
    bf_hat: np.ndarray,
    u_prev: np.ndarray,
) -> None:
    ths, _B, _scale = vessel(name)
    step = ths.max_step(DT_S)
    res = alloc_obj.allocate(tau_d, delta_hat, bf_hat, u_prev)
    u = res.u
    assert u.shape == (ths.m,)
    assert np.all(np.isfinite(u))
    lo, hi = command_bounds(ths.u_min, ths.u_max, step, u_prev)
    assert np.all(u >= lo - 1e-9) and np.all(u <= hi + 1e-9), (u, lo, hi, res.status)
    dead = delta_hat < alloc_obj.config.dead_threshold
    np.testing.assert_array_equal(res.dead, dead)
    # A dead thruster is ramped to zero as fast as the rate limit allows, never reversed.
    expected = np.maximum(np.abs(u_prev) - step, 0.0)
    assert np.all(np.abs(np.abs(u[dead]) - expected[dead]) <= 1e-12)
    assert np.all(u[dead] * u_prev[dead] >= 0.0)
    assert np.all(u[dead & (u_prev == 0.0)] == 0.0)
    assert not np.any(res.saturated & dead)
    assert res.status in (AllocationStatus.OK, AllocationStatus.FALLBACK)
    assert np.all(np.isfinite(res.tau_planned))


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("name", sorted(VESSELS))
def test_allocation_invariants(name: str, backend: str) -> None:
    @settings(max_examples=80, deadline=None)
    @given(p=problem(name, MAX_EXPONENT[backend]))
    def run(p: tuple[np.ndarray, ...]) -> None:
        check_invariants(shared_allocator(name, backend), name, *p)

    run()


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("magnitude", [1e12, 1e300])
def test_huge_demand_invariants(backend: str, magnitude: float) -> None:
    _ths, _B, scale = vessel("paper4")
    alloc = fresh_allocator("paper4", backend)
    for sign in (1.0, -1.0):
        tau_d = sign * np.array([1.0, -0.5, 0.3]) * scale * magnitude
        u_prev = np.array([0.05, -0.1, 0.0, 0.1])
        check_invariants(
            alloc, "paper4", tau_d, np.array([1.0, 0.5, 0.05, 1.0]), np.zeros(3), u_prev
        )


def test_proxqp_iteration_budget_on_huge_demand() -> None:
    _ths, _B, scale = vessel("paper4")
    alloc = fresh_allocator("paper4", "proxqp")
    res = alloc.allocate(
        np.array([1.0, -0.5, 0.3]) * scale * 1e300, np.ones(4), np.zeros(3), np.zeros(4)
    )
    # The demand is shrunk along its direction before the QP: a normal, quick solve that
    # saturates towards it (before: 300200 proxqp iterations, 0.5-3 s, then FALLBACK).
    assert res.status is AllocationStatus.OK
    assert res.iterations <= 200
    lo, hi = alloc.bounds(np.zeros(4), np.zeros(4, dtype=bool))
    assert np.all(res.u >= lo - 1e-12) and np.all(res.u <= hi + 1e-12)


@st.composite
def feasible_problem(draw: st.DrawFn, name: str) -> tuple[np.ndarray, ...]:
    ths, B, scale = vessel(name)
    m = ths.m
    delta = 0.2 + 0.8 * draw(unit_floats(m))  # all live
    frac = draw(unit_floats(m)) * 2.0 - 1.0
    u_true = 0.5 * np.where(frac >= 0, frac * ths.u_max, -frac * ths.u_min)
    bf = (draw(unit_floats(3)) * 2.0 - 1.0) * scale * 0.2
    tau_d = B @ (delta * u_true) + bf
    return tau_d, delta, bf, u_true


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("name", sorted(VESSELS))
def test_feasible_demand_is_met(name: str, backend: str) -> None:
    _ths, _B, scale = vessel(name)

    @settings(max_examples=60, deadline=None)
    @given(p=feasible_problem(name))
    def run(p: tuple[np.ndarray, ...]) -> None:
        tau_d, delta, bf, u_true = p
        res = shared_allocator(name, backend).allocate(tau_d, delta, bf, u_prev=u_true)
        assert res.status is AllocationStatus.OK
        assert np.max(np.abs(res.tau_planned - tau_d) / scale) <= 1e-4
        np.testing.assert_allclose(res.unallocated, tau_d - res.tau_planned, rtol=0, atol=1e-15)

    run()


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_demand_is_flagged(backend: str, bad: float) -> None:
    ths, _B, scale = vessel("paper4")
    alloc = fresh_allocator("paper4", backend)
    u_prev = np.array([0.05, -0.08, 0.0, 0.08])
    res = alloc.allocate(np.array([0.01, bad, 0.0]), np.ones(4), np.zeros(3), u_prev)
    assert res.status is AllocationStatus.INVALID_DEMAND
    assert np.all(np.isfinite(res.u))
    lo, hi = command_bounds(ths.u_min, ths.u_max, ths.max_step(DT_S), u_prev)
    assert np.all(lo <= res.u) and np.all(res.u <= hi)
    # Zero demand is allocated instead (reachable in one step from this u_prev).
    assert np.max(np.abs(res.tau_planned) / scale) <= 1e-4


def test_backends_agree() -> None:
    backends = available_backends()
    assert {"proxqp", "daqp", "qpsolvers:proxqp"} <= set(backends)
    rng = np.random.default_rng(7)
    for name in sorted(VESSELS):
        ths, _B, scale = vessel(name)
        allocators = {b: fresh_allocator(name, b) for b in backends}
        m = ths.m
        for _ in range(50):
            tau_d = rng.uniform(-1.5, 1.5, 3) * scale
            delta_hat = np.where(rng.random(m) < 0.15, 0.0, rng.uniform(0.3, 1.0, m))
            bf_hat = rng.uniform(-0.2, 0.2, 3) * scale
            u_prev = rng.uniform(ths.u_min, ths.u_max)
            u_pref = rng.uniform(-0.05, 0.05, m) * (ths.u_max - ths.u_min)
            results = {
                b: a.allocate(tau_d, delta_hat, bf_hat, u_prev, u_pref)
                for b, a in allocators.items()
            }
            ref = results["proxqp"].u
            for b, res in results.items():
                assert res.status is AllocationStatus.OK, b
                np.testing.assert_allclose(res.u, ref, rtol=0, atol=1e-4, err_msg=b)


@pytest.mark.parametrize("backend", ["proxqp", "daqp"])
def test_warm_start_matches_cold_solve_under_constant_demand(backend: str) -> None:
    """A constant demand that needs several rate steps: every cycle's command must equal a
    cold solve of the same problem, and the ramp must reach the demand."""
    ths = paper_four_thrusters(step_limit=0.02)
    B = effectiveness(ths)
    scale = wrench_scale(B, ths.u_min, ths.u_max)
    warm = Allocator(B, ths, DT_S, scale, AllocatorConfig(backend=backend))
    tau_d = np.array([0.2, 0.05, 0.01])
    u = np.zeros(4)
    for _ in range(8):
        cold = Allocator(B, ths, DT_S, scale, AllocatorConfig(backend="daqp"))
        expected = cold.allocate(tau_d, np.ones(4), np.zeros(3), u).u
        u = warm.allocate(tau_d, np.ones(4), np.zeros(3), u).u
        np.testing.assert_allclose(u, expected, atol=1e-6)
    np.testing.assert_allclose(B @ u, tau_d, atol=1e-5)


@pytest.mark.parametrize("backend", ["proxqp", "daqp"])
def test_reused_H_follows_delta_hat(backend: str) -> None:
    """The allocator reuses its H while delta_hat moves by <= 1e-9 and rebuilds it beyond
    that, or after a retune: every command must match a fresh allocator's (no stale H)."""
    ths, B, scale = vessel("paper4")
    warm = fresh_allocator("paper4", backend)
    tau_d = np.array([0.08, -0.03, 0.01])
    u = np.zeros(4)
    # Tiny drifts (reused), then a weak thruster (rebuilt), a dead one, and a recovery.
    steps = [np.ones(4) - 3e-10 * i for i in range(4)]
    steps += [np.array([1.0, 0.5, 1.0, 1.0]), np.array([1.0, 0.5, 0.0, 1.0]), np.ones(4)]
    Hs = []
    for delta_hat in steps:
        cold = fresh_allocator("paper4", "daqp")
        expected = cold.allocate(tau_d, delta_hat, np.zeros(3), u).u
        u = warm.allocate(tau_d, delta_hat, np.zeros(3), u).u
        np.testing.assert_allclose(u, expected, atol=1e-6)
        Hs.append(warm._H)
    assert all(H is Hs[0] for H in Hs[:4])  # drift below 1e-9: the same array, no set-up
    assert len({id(H) for H in Hs[3:]}) == 4  # every real change rebuilt it
    cfg = AllocatorConfig(backend=backend, effort_weight=1e3)  # a retune must rebuild it too
    warm.retune(cfg)
    cold = Allocator(B, ths, DT_S, scale, cfg)
    expected = cold.allocate(tau_d, np.ones(4), np.zeros(3), u).u
    np.testing.assert_allclose(
        warm.allocate(tau_d, np.ones(4), np.zeros(3), u).u, expected, atol=1e-6
    )


class FailingSolver:
    """Test double of the BoxQpSolver protocol: every solve fails (returns NaN, found=False)."""

    name = "failing"

    def __init__(self) -> None:
        self.calls = 0

    def solve(self, H: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> BoxQpSolution:
        self.calls += 1
        return BoxQpSolution(np.full_like(g, np.nan), False)


@pytest.mark.parametrize("name", sorted(VESSELS))
def test_solver_failure_falls_back_within_bounds(name: str) -> None:
    ths, B, scale = vessel(name)
    alloc = fresh_allocator(name, "proxqp")
    double = FailingSolver()
    alloc._solver = double
    rng = np.random.default_rng(3)
    step = ths.max_step(DT_S)
    for _ in range(30):
        delta_hat = np.where(rng.random(ths.m) < 0.2, 0.0, rng.uniform(0.3, 1.0, ths.m))
        u_prev = rng.uniform(ths.u_min, ths.u_max)
        tau_d = rng.uniform(-3.0, 3.0, 3) * scale
        res = alloc.allocate(tau_d, delta_hat, np.zeros(3), u_prev)
        assert res.status is AllocationStatus.FALLBACK
        assert np.all(np.isfinite(res.u))
        lo, hi = command_bounds(ths.u_min, ths.u_max, step, u_prev)
        assert np.all(lo <= res.u) and np.all(res.u <= hi)
        dead = delta_hat < 0.1
        np.testing.assert_allclose(
            np.abs(res.u[dead]), np.maximum(np.abs(u_prev[dead]) - step[dead], 0.0), atol=1e-12
        )
    assert double.calls == 30
    assert alloc.backend == "failing"


def test_solver_failure_with_bad_demand_keeps_invalid_status() -> None:
    alloc = fresh_allocator("paper4", "daqp")
    alloc._solver = FailingSolver()
    res = alloc.allocate(np.array([np.nan, 0.0, 0.0]), np.ones(4), np.zeros(3), np.zeros(4))
    assert res.status is AllocationStatus.INVALID_DEMAND
    np.testing.assert_array_equal(res.u, np.zeros(4))


def test_fallback_feasible_demand_is_pseudo_inverse() -> None:
    """With a failed solver and a demand well inside the box, the fallback is pinv(B) tau."""
    ths, B, _scale = vessel("paper4")
    alloc = fresh_allocator("paper4", "proxqp")
    alloc._solver = FailingSolver()
    u_true = np.array([0.02, -0.01, 0.015, 0.0])
    tau_d = B @ u_true
    res = alloc.allocate(tau_d, np.ones(4), np.zeros(3), u_true)
    np.testing.assert_allclose(res.u, np.linalg.pinv(B) @ tau_d, atol=1e-15)
    np.testing.assert_allclose(res.tau_planned, tau_d, atol=1e-15)


def test_saturation_reported() -> None:
    """A demand far beyond reach saturates the live thrusters at their bounds."""
    ths, B, scale = vessel("paper4")
    alloc = fresh_allocator("paper4", "daqp")
    res = alloc.allocate(np.array([10.0, 0.0, 0.0]), np.ones(4), np.zeros(3), np.zeros(4))
    # Surge only: T1, T2 forward, T3, T4 backward, each at its rate limit 0.09 from rest.
    np.testing.assert_allclose(res.u, [0.09, 0.09, -0.09, -0.09], atol=1e-9)
    assert res.saturated.all()
    assert res.unallocated[0] > 9.0


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        ({"dead_threshold": 1.0}, "dead_threshold"),
        ({"dead_threshold": -0.1}, "dead_threshold"),
        ({"slack_weight": 0.0}, "slack_weight"),
        ({"effort_weight": -1.0}, "effort_weight"),
    ],
)
def test_config_errors_name_key(kwargs: dict[str, float], key: str) -> None:
    with pytest.raises(ValueError, match=key):
        AllocatorConfig(**kwargs)


def test_unknown_backend_is_named() -> None:
    ths, B, scale = vessel("paper4")
    with pytest.raises(ValueError, match="qp backend 'nope'"):
        Allocator(B, ths, DT_S, scale, AllocatorConfig(backend="nope"))


@pytest.mark.parametrize("backend", BACKENDS)
def test_full_scale_ranges_realise_a_null_space_preference(backend: str) -> None:
    """The supply vessel's thrusters (200 kN tunnels, 800 kN mains): a preference in the null
    space of B is the optimum, exactly. In newtons H spans 1e-11 (effort) to 1e-6 (slack),
    below the solvers' zero tolerances: unscaled, daqp returned 40 % of it and proxqp gave
    up after 1000 iterations."""
    from ftcap_hil.config.presets import load_preset

    preset = load_preset("supply")
    ths, B = preset.thrusters, preset.B
    scale = wrench_scale(B, ths.u_min, ths.u_max)
    alloc = Allocator(B, ths, 0.5, scale, AllocatorConfig(backend=backend))
    _u, _s, vt = np.linalg.svd(B * np.maximum(-ths.u_min, ths.u_max))
    z = vt[3:].T @ np.array([1.0, -0.5, 0.25])
    u_pref = 0.2 * np.maximum(-ths.u_min, ths.u_max) * z / np.abs(z).max()
    assert np.abs(B @ u_pref).max() < 1e-6 * np.abs(u_pref).max()
    m = ths.m
    res = alloc.allocate(np.zeros(3), np.ones(m), np.zeros(3), np.zeros(m), u_pref)
    assert res.status is AllocationStatus.OK
    np.testing.assert_allclose(res.u, u_pref, rtol=0, atol=1e-3 * np.abs(u_pref).max())
