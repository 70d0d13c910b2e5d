"""The cycle's lean paths (issue 25) against the reference computations they replace.

Each fast path does the reference's operations in the reference's order (in Python floats
where numpy's per-call overhead dominated, or skipping work whose inputs are the very same
objects as last cycle), so the results are compared to the last bit where the reference is
the same arithmetic, and to 1e-12 relative against an independent computation otherwise.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from types import SimpleNamespace

import numpy as np
import pytest

from ftcap_hil.core.allocation.allocator import Allocator
from ftcap_hil.core.allocation.qp import _bound_size
from ftcap_hil.core.cycle import CoreConfig, FtcapCore
from ftcap_hil.core.effectiveness.geometry import effectiveness, paper_four_thrusters
from ftcap_hil.core.estimation.config import EstimatorConfig, wrench_scale
from ftcap_hil.core.estimation.decisions import _best
from ftcap_hil.core.estimation.kalman import KalmanEstimator
from ftcap_hil.core.estimation.shaft_channel import Channel
from ftcap_hil.core.estimation.stages import Observation
from ftcap_hil.core.estimation.step_models import VesselStep, inv_small
from ftcap_hil.core.models.plants import SurfaceVessel
from ftcap_hil.core.models.vessel3dof import DAMPING_KEYS, Vessel3DOF

THS = paper_four_thrusters()
B = effectiveness(THS)
DT = 0.2827


def some_vessel(rng: np.random.Generator, coriolis: bool) -> Vessel3DOF:
    """A Vessel3DOF with every coefficient non-zero (a CG offset, added mass, all damping)."""
    damping = {k: -abs(float(rng.normal(1.0, 0.5))) for k in DAMPING_KEYS}
    return Vessel3DOF(
        mass_kg=23.8, iz_kgm2=1.76, xg_m=0.046, X_udot=-2.0, Y_vdot=-10.0, Y_rdot=-0.1,
        N_vdot=-0.1, N_rdot=-1.0, coriolis=coriolis, **damping,
    )  # fmt: skip


@pytest.mark.parametrize("coriolis", [True, False])
def test_one_state_nu_dot_is_the_array_arithmetic_to_the_bit(coriolis: bool) -> None:
    rng = np.random.default_rng(7)
    plant = some_vessel(rng, coriolis)
    for n in range(2000):
        nu = rng.normal(size=3) * [0.01, 0.1, 1.0, 10.0][n % 4]
        if n % 5 == 0:
            nu[n % 3] = 0.0
        tau = rng.normal(size=3) * 5.0
        reference = (tau - plant.hydro_and_coriolis(nu)) @ plant._m_inv_t
        fast = plant.nu_dot(nu, tau)
        assert np.array_equal(fast, reference)
        batch = plant.nu_dot(nu[None, :], tau[None, :])[0]  # the array path
        np.testing.assert_allclose(fast, batch, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("coriolis", [True, False])
def test_one_state_damping_is_the_batch_one_to_the_bit(coriolis: bool) -> None:
    rng = np.random.default_rng(8)
    plant = some_vessel(rng, coriolis)
    for _ in range(500):
        nu = rng.normal(size=3)
        assert np.array_equal(plant.damping(nu), plant.damping(nu[None, :])[0])


def scanned(history: deque[tuple[float, ...]], t_s: float) -> tuple[float, ...]:
    """The linear scan predicted_at replaced (the reference)."""
    prev = history[0]
    for entry in history:
        if entry[0] >= t_s:
            dt = entry[0] - prev[0]
            w = 1.0 if dt <= 0.0 else (t_s - prev[0]) / dt
            return tuple(p + w * (e - p) for p, e in zip(prev[1:], entry[1:], strict=True))
        prev = entry
    return prev[1:]


def test_the_predicted_speed_is_the_scanned_one_to_the_bit() -> None:
    rng = np.random.default_rng(9)
    times = np.cumsum(rng.uniform(0.001, 0.2, size=60))
    history = deque((float(t), *map(float, rng.normal(size=3))) for t in times)
    channel = SimpleNamespace(history=history)
    for t_s in [*rng.uniform(-1.0, times[-1] + 1.0, size=500), *times, times[0] - 1.0]:
        assert Channel.predicted_at(channel, float(t_s)) == scanned(history, float(t_s))  # type: ignore[arg-type]


def test_the_paper_vessels_step_is_the_generic_one_to_the_bit() -> None:
    rng = np.random.default_rng(3)
    step = VesselStep(SurfaceVessel())
    for n in range(2000):
        s0 = rng.normal(size=3) * [0.01, 0.1, 1.0][n % 3]
        w = rng.normal(size=3) * 0.1
        dt = float(rng.uniform(0.01, 1.0))
        s1, A, G = step.one(s0, w, dt)
        f0 = step.plant.nu_dot(s0, w)
        A_ref = dt * step._jacobian(s0, w, f0)
        A_ref[np.diag_indices(3)] += 1.0
        assert np.array_equal(s1, s0 + dt * f0)
        assert np.array_equal(A, A_ref)
        assert np.array_equal(G, dt * step._minv)


@pytest.mark.parametrize("n", [1, 2, 3])
def test_inv_small_inverts_to_1e_12(n: int) -> None:
    rng = np.random.default_rng(n)
    for _ in range(500):
        M = rng.normal(size=(n, n))
        a = M @ M.T + 0.1 * np.eye(n)
        np.testing.assert_allclose(inv_small(a) @ a, np.eye(n), atol=1e-12)


def test_bound_size_leaves_out_nan_and_the_infinite_stand_in() -> None:
    big = 1e20
    assert _bound_size(np.array([0.3, big]), np.array([-2.5, -big])) == 2.5
    assert _bound_size(np.array([0.3, math.nan]), np.array([-0.2, 0.1])) == 1.0
    assert _bound_size(np.array([0.3, math.nan]), np.array([-7.0, 0.1])) == 7.0


def test_an_absurd_demand_is_shrunk_and_a_nan_one_left_alone() -> None:
    S = wrench_scale(B, THS.u_min, THS.u_max)
    alloc = Allocator(B, THS, DT, S)
    huge = alloc._shrunk(np.array([1e308, 0.0, -1e308]))
    np.testing.assert_allclose(np.abs(huge / S).max(), 10.0)
    assert huge[0] > 0.0 > huge[2]
    nan = np.array([math.nan, 1e308, 0.0])
    assert alloc._shrunk(nan) is nan


def test_the_greedy_pick_is_numpys_argmax_of_the_qualifying_scores() -> None:
    rng = np.random.default_rng(5)
    for n in range(3000):
        m = [1, 3, 4, 16][n % 4]
        f = rng.normal(size=m) * rng.choice([0.1, 1.0, 10.0], size=m)
        f[rng.random(m) < 0.1] = math.nan
        f[rng.random(m) < 0.2] = 2.0  # ties
        root, big = np.abs(rng.normal(size=m)) + 0.5, rng.uniform(0.0, 1.0, size=m)
        need = np.where(rng.random(m) < 0.5, 2.0, 4.0)
        on = rng.random(m) < 0.3
        score = np.abs(f) * root
        ok = (score > need) & (np.abs(f) >= big) & ~on
        expected = int(np.argmax(np.where(ok, score, -np.inf))) if ok.any() else -1
        args = (f.tolist(), root.tolist(), need.tolist(), big.tolist(), on.tolist())
        assert _best(*args) == expected


def projected(z: np.ndarray, P: np.ndarray, ks: int, m: int) -> np.ndarray:
    """The projection's reference arithmetic (KalmanEstimator._project as it was)."""
    z = z.copy()
    d = z[ks : ks + m]
    low, high = d < 0.0, d > 1.0
    active = np.flatnonzero(low | high)
    if active.size:
        rows = ks + active
        gap = z[rows] - np.where(low[active], 0.0, 1.0)
        z -= P[:, rows] @ np.linalg.solve(P[np.ix_(rows, rows)], gap)
        np.clip(z[ks : ks + m], 0.0, 1.0, out=z[ks : ks + m])
    return z


def test_the_projection_is_the_reference_one_to_the_bit() -> None:
    rng = np.random.default_rng(12)
    S = wrench_scale(B, THS.u_min, THS.u_max)
    kf = KalmanEstimator(B, S, SurfaceVessel(), EstimatorConfig(measurement_std=(1e-3,) * 3))
    ks, m, n = 3, 4, kf.P.shape[0]
    for k in range(1000):
        M = rng.normal(size=(n, n))
        kf.P = M @ M.T / n + 1e-6 * np.eye(n)
        kf.z = rng.normal(size=n)
        kf.z[ks : ks + m] = rng.uniform(-0.2, 1.2, size=m) if k % 3 else rng.uniform(0, 1, m)
        expected = projected(kf.z, kf.P, ks, m)
        kf._project()
        assert np.array_equal(kf.z, expected)


def cycles(core: FtcapCore, forget: bool) -> list[np.ndarray]:
    """120 cycles of example-1-like demands, a sample every third cycle; ``forget``: the
    kept judged output and excitation dropped before every cycle (the reference)."""
    rng = np.random.default_rng(11)
    plant, x, out = SurfaceVessel(), np.zeros(6), []
    for n in range(120):
        tau_d = rng.normal(0.0, 0.05, size=3)
        obs = None
        if n % 3 == 0:
            x_new = plant.step(x, B @ (core.u_prev * [1.0, 1.0, 0.5 if n > 40 else 1.0, 1.0]), DT)
            obs, x = Observation(x, x_new, DT), x_new
        if forget:
            core._judged, core._excited = None, None
        res = core.step(tau_d, obs)
        out += [res.u, res.estimate.delta_hat, res.allocation.unallocated, res.probing]
    return out


@pytest.mark.parametrize("kind", ["kalman", "windowed"])
def test_cycles_without_a_sample_match_the_recomputed_ones_to_the_bit(kind: str) -> None:
    est = dataclasses.replace(EstimatorConfig(), measurement_std=(1e-4, 1e-4, 1e-4))
    est = dataclasses.replace(est, kind=type(est.kind)(kind))
    cfg = CoreConfig(estimator=est)
    lean = cycles(FtcapCore(B, THS, DT, cfg, SurfaceVessel()), forget=False)
    reference = cycles(FtcapCore(B, THS, DT, cfg, SurfaceVessel()), forget=True)
    assert len(lean) == len(reference)
    for a, b in zip(lean, reference, strict=True):
        assert np.array_equal(a, b)
