"""The 3-DOF truth model (Vessel3DOF) against hand-computed values and invariants."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ftcap_hil.core.models.plants import Inversion, SurfaceVessel
from ftcap_hil.core.models.vessel3dof import Vessel3DOF

# A small made-up vessel; every expected number below is worked out by hand from it.
SMALL = Vessel3DOF(
    mass_kg=10.0,
    iz_kgm2=2.0,
    xg_m=0.1,
    X_udot=-1.0,
    Y_vdot=-3.0,
    Y_rdot=-0.4,
    N_vdot=-0.4,
    N_rdot=-0.5,
    X_u=-2.0,
    X_uu=-1.0,
    X_uuu=-0.5,
    Y_v=-3.0,
    Y_vv=-2.0,
    Y_r=-0.3,
    Y_rv=-0.1,
    Y_vr=-0.2,
    Y_rr=-0.05,
    N_v=-0.2,
    N_vv=-0.1,
    N_r=-1.0,
    N_rv=-0.3,
    N_vr=-0.15,
    N_rr=-0.4,
)


def test_mass_matrices_are_the_literal_ones() -> None:
    np.testing.assert_array_equal(
        SMALL.rigid_body_mass, [[10.0, 0.0, 0.0], [0.0, 10.0, 1.0], [0.0, 1.0, 2.0]]
    )
    np.testing.assert_array_equal(
        SMALL.added_mass, [[1.0, 0.0, 0.0], [0.0, 3.0, 0.4], [0.0, 0.4, 0.5]]
    )
    np.testing.assert_allclose(
        SMALL.mass_matrix, [[11.0, 0.0, 0.0], [0.0, 13.0, 1.4], [0.0, 1.4, 2.5]], rtol=1e-15
    )


def test_coriolis_terms_equal_fossens_matrices_times_nu() -> None:
    nu = np.array([1.0, 0.5, 0.2])
    # C_RB(nu) = [[0, 0, -m(x_g r + v)], [0, 0, m u], [m(x_g r + v), -m u, 0]]
    c_rb = np.array([[0.0, 0.0, -5.2], [0.0, 0.0, 10.0], [5.2, -10.0, 0.0]])
    # C_A(nu) = [[0, 0, a], [0, 0, b], [-a, -b, 0]], a = Y_vdot v + (Y_rdot + N_vdot)/2 r
    # = -1.5 - 0.08, b = -X_udot u = 1
    c_a = np.array([[0.0, 0.0, -1.58], [0.0, 0.0, 1.0], [1.58, -1.0, 0.0]])
    np.testing.assert_allclose(SMALL.coriolis_rigid_body(nu), c_rb @ nu, rtol=1e-14)
    np.testing.assert_allclose(SMALL.coriolis_added(nu), c_a @ nu, rtol=1e-14)
    np.testing.assert_allclose(SMALL.coriolis_rigid_body(nu), [-1.04, 2.0, 0.2], rtol=1e-14)
    np.testing.assert_allclose(SMALL.coriolis_added(nu), [-0.316, 0.2, 1.08], rtol=1e-14)


def test_damping_is_the_literal_matrix_times_nu() -> None:
    nu = np.array([1.0, -0.5, 0.2])
    # d11 = 2 + 1 + 0.5; d22 = 3 + 2(0.5) + 0.1(0.2); d23 = 0.3 + 0.2(0.5) + 0.05(0.2);
    # d32 = 0.2 + 0.1(0.5) + 0.3(0.2); d33 = 1 + 0.15(0.5) + 0.4(0.2)
    d = np.array([[3.5, 0.0, 0.0], [0.0, 4.02, 0.41], [0.0, 0.31, 1.155]])
    np.testing.assert_allclose(SMALL.damping(nu), d @ nu, rtol=1e-14)
    np.testing.assert_allclose(SMALL.damping(nu), [3.5, -1.928, 0.076], rtol=1e-13)


def test_pure_yaw_rate_gives_the_centripetal_force_of_the_offset_mass() -> None:
    """nu = (0, 0, r): X = -(m x_g - (Y_rdot + N_vdot)/2) r^2 = -(1 + 0.4) r^2, Y = N = 0."""
    v = Vessel3DOF(mass_kg=10.0, iz_kgm2=2.0, xg_m=0.1, Y_rdot=-0.4, N_vdot=-0.4)
    r = 0.5
    np.testing.assert_allclose(v.hydro_and_coriolis(np.array([0.0, 0.0, r])), [-0.35, 0, 0])
    # surge plus yaw: Y = (m - X_udot) u r, the Munk moment (X_udot - Y_vdot) u v is 0 at v = 0
    u, nu = 2.0, np.array([2.0, 0.0, r])
    total = SMALL.coriolis_rigid_body(nu) + SMALL.coriolis_added(nu)
    np.testing.assert_allclose(total, [-1.4 * r * r, 11.0 * u * r, 1.4 * u * r], rtol=1e-14)


def test_a_vessel_at_rest_in_a_current_feels_the_drag_of_minus_the_current() -> None:
    """0.2 m/s current to the north, vessel at rest heading north: nu_r = (-0.2, 0, 0), so
    M nu_dot = -D(nu_r) nu_r = -(X_u + X_uu 0.2 + X_uuu 0.04)(0.2) = 2.22 * 0.2 = 0.444 N."""
    x = np.zeros(6)
    nu_c = Vessel3DOF.current_body(0.0, np.array([0.2, 0.0]))
    np.testing.assert_allclose(nu_c, [0.2, 0.0, 0.0])
    m_nu_dot = SMALL.mass_matrix @ SMALL.nu_dot(x[3:], np.zeros(3), nu_c)
    np.testing.assert_allclose(m_nu_dot, [0.444, 0.0, 0.0], atol=1e-15)
    # heading east, the same northward current comes from port: nu_c = (0, -0.2, 0)
    nu_c_east = Vessel3DOF.current_body(math.pi / 2, np.array([0.2, 0.0]))
    np.testing.assert_allclose(nu_c_east, [0.0, -0.2, 0.0], atol=1e-16)


def test_a_vessel_drifting_with_the_current_feels_nothing() -> None:
    current = np.array([0.15, -0.1])
    x = np.array([3.0, 4.0, 0.7, 0.0, 0.0, 0.0])
    x[3:] = Vessel3DOF.current_body(0.7, current)
    np.testing.assert_allclose(SMALL.nu_dot(x[3:], np.zeros(3), x[3:]), 0.0, atol=1e-16)
    x1 = SMALL.step_rk4(x, np.zeros(3), 10.0, substeps=20, current_ned=current)
    np.testing.assert_allclose(x1[:2], x[:2] + 10.0 * current, rtol=1e-12)
    np.testing.assert_allclose(x1[2:], x[2:], atol=1e-14)


def test_motion_in_a_current_is_still_water_motion_carried_by_it() -> None:
    """Galilean invariance (constant irrotational current): with nu_r(0) equal, the paths
    differ only by V_c t, even while turning (C_RB(nu) nu vs C_A(nu_r) nu_r split)."""
    current = np.array([0.3, 0.2])
    tau = np.array([1.0, -0.5, 0.3])
    still = np.array([0.0, 0.0, 0.4, 0.5, 0.1, 0.2])
    moving = still.copy()
    moving[3:] += Vessel3DOF.current_body(0.4, current)
    for _ in range(50):
        still = SMALL.step_rk4(still, tau, 0.1, substeps=4)
        moving = SMALL.step_rk4(moving, tau, 0.1, substeps=4, current_ned=current)
    np.testing.assert_allclose(moving[:2] - still[:2], 5.0 * current, atol=1e-7)
    np.testing.assert_allclose(moving[2], still[2], atol=1e-9)


def test_the_papers_parameters_reproduce_surface_vessel() -> None:
    sv = SurfaceVessel()
    v = Vessel3DOF.from_surface_vessel(sv)
    rng = np.random.default_rng(1)
    nus, taus = rng.normal(size=(500, 3)), rng.normal(scale=0.1, size=(500, 3))
    expected = np.array([sv.nu_dot(nu, tau) for nu, tau in zip(nus, taus, strict=True)])
    np.testing.assert_allclose(v.nu_dot(nus, taus), expected, rtol=0, atol=1e-12)
    x = np.array([1.0, 2.0, 0.3, 0.5, -0.2, 0.1])
    tau = np.array([0.1, -0.05, 0.02])
    np.testing.assert_allclose(v.step(x, tau, 0.1), sv.step(x, tau, 0.1), atol=1e-12)
    np.testing.assert_allclose(v.step_rk4(x, tau, 0.1), sv.step_rk4(x, tau, 0.1), atol=1e-12)
    for inversion in Inversion:
        a = SurfaceVessel(inversion=inversion)
        b = Vessel3DOF.from_surface_vessel(a)
        x1 = a.step_rk4(x, tau, 0.2)
        np.testing.assert_allclose(
            b.measured_wrench(x, x1, 0.2), a.measured_wrench(x, x1, 0.2), atol=1e-12
        )


def _energy(v: Vessel3DOF, x: np.ndarray) -> float:
    return float(0.5 * x[3:] @ v.mass_matrix @ x[3:])


def test_kinetic_energy_never_grows_without_forcing() -> None:
    rng = np.random.default_rng(2)
    for _ in range(5):
        x = np.concatenate([np.zeros(3), rng.normal(scale=1.0, size=3)])
        energies = [_energy(SMALL, x)]
        for _ in range(400):
            x = SMALL.step_rk4(x, np.zeros(3), 0.02, substeps=2)
            energies.append(_energy(SMALL, x))
        assert np.all(np.diff(energies) <= 1e-12 * energies[0])
        assert energies[-1] < 0.5 * energies[0]  # and the damping does take it out


def test_coriolis_does_no_work() -> None:
    """Undamped, the skew-symmetric C_RB + C_A conserve 1/2 nu^T M nu exactly (RK4 error)."""
    undamped = Vessel3DOF(
        mass_kg=10.0, iz_kgm2=2.0, xg_m=0.1, X_udot=-1.0, Y_vdot=-3.0,
        Y_rdot=-0.4, N_vdot=-0.4, N_rdot=-0.5,
    )  # fmt: skip
    x = np.array([0.0, 0.0, 0.0, 1.0, -0.7, 0.9])
    e0 = _energy(undamped, x)
    for _ in range(500):
        x = undamped.step_rk4(x, np.zeros(3), 0.01, substeps=2)
    assert _energy(undamped, x) == pytest.approx(e0, rel=1e-9)
    assert abs(x[4] + 0.7) > 0.1  # the state did move: energy is traded between axes


def test_euler_inversion_undoes_a_step_and_trapezoid_beats_it_on_rk4() -> None:
    x0 = np.array([0.0, 0.0, 0.3, 0.5, -0.2, 0.1])
    tau = np.array([2.0, -1.0, 0.4])
    euler = SMALL
    x1 = euler.step(x0, tau, 0.05)
    np.testing.assert_allclose(euler.measured_wrench(x0, x1, 0.05), tau, atol=1e-12)
    trap = dataclasses.replace(SMALL, inversion=Inversion.TRAPEZOID)
    x1 = SMALL.step_rk4(x0, tau, 0.2, substeps=16)
    e_euler = np.abs(euler.measured_wrench(x0, x1, 0.2) - tau).max()
    e_trap = np.abs(trap.measured_wrench(x0, x1, 0.2) - tau).max()
    assert e_trap < 0.2 * e_euler


def test_batched_calls_equal_row_by_row() -> None:
    rng = np.random.default_rng(3)
    nus, taus, cur = rng.normal(size=(50, 3)), rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    cur[:, 2] = 0.0
    rows = np.array([SMALL.nu_dot(n, t, c) for n, t, c in zip(nus, taus, cur, strict=True)])
    np.testing.assert_allclose(SMALL.nu_dot(nus, taus, cur), rows, rtol=1e-14)


def test_tau_env_is_an_extra_body_wrench() -> None:
    nu = np.array([0.3, 0.1, -0.2])
    tau, env = np.array([1.0, 2.0, 0.5]), np.array([-0.4, 0.3, 0.1])
    np.testing.assert_allclose(SMALL.nu_dot(nu, tau, None, env), SMALL.nu_dot(nu, tau + env))


def test_scaled_multiplies_inertia_and_damping() -> None:
    s = SMALL.scaled(mass=1.2, damping=0.7)
    np.testing.assert_allclose(s.mass_matrix, 1.2 * SMALL.mass_matrix, rtol=1e-15)
    nu = np.array([1.0, -0.5, 0.2])
    np.testing.assert_allclose(s.damping(nu), 0.7 * SMALL.damping(nu), rtol=1e-14)
    assert s.xg_m == SMALL.xg_m


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(ValueError, match="positive definite"):
        Vessel3DOF(mass_kg=1.0, iz_kgm2=1.0, X_udot=2.0)
    with pytest.raises(ValueError, match="inversion"):
        Vessel3DOF(mass_kg=1.0, iz_kgm2=1.0, inversion="rk4")
    with pytest.raises(ValueError, match="mass_kg"):
        Vessel3DOF(mass_kg=0.0, iz_kgm2=1.0)


@pytest.mark.parametrize("coriolis", [True, False])
def test_the_integrators_use_the_equations_of_nu_dot(coriolis: bool) -> None:
    """step/step_rk4 run a float-only copy of the equations: it must equal nu_dot's."""
    v = dataclasses.replace(SMALL, coriolis=coriolis)
    rng = np.random.default_rng(4)
    for _ in range(200):
        x, tau = rng.normal(size=6), rng.normal(size=3)
        cur, env = rng.normal(scale=0.3, size=2), rng.normal(size=3)
        nu_c = Vessel3DOF.current_body(float(x[2]), cur)
        expected = np.concatenate(
            [SurfaceVessel.eta_dot(x[:3], x[3:]), v.nu_dot(x[3:], tau, nu_c, env)]
        )
        got = (v.step(x, tau, 1e-3, cur, env) - x) / 1e-3
        np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9)
