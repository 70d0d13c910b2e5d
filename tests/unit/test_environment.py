"""The environment (sim/environment.py): off by default, seeded, statistics of long runs,
and each force model against a hand-computed or independently integrated value."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.environment import (
    RHO_AIR_KG_M3,
    CurrentConfig,
    Environment,
    EnvironmentConfig,
    HullGeometry,
    WaveConfig,
    WindCoefficients,
    WindConfig,
    froude_krylov,
    jonswap,
    wind_wrench,
)

HULL = HullGeometry(l_oa_m=76.2, beam_m=19.2, draft_m=6.0, a_front_m2=300.0, a_lateral_m2=800.0)
SEA = WaveConfig(hs_m=2.5, tp_s=8.0, direction_rad=math.radians(30.0))
AT_REST = np.zeros(6)


def long_run(f, t_end: float, dt: float, chunks: int = 20) -> np.ndarray:  # type: ignore[no-untyped-def]
    t = np.arange(0.0, t_end, dt)
    return np.concatenate([f(part) for part in np.array_split(t, chunks)])


def test_everything_is_off_by_default() -> None:
    env = Environment(EnvironmentConfig(), HULL)
    assert env.calm
    s = env.sample(12.3, np.array([1.0, 2.0, 0.3, 0.5, 0.1, 0.0]))
    np.testing.assert_array_equal(s.current_ned, [0.0, 0.0])
    np.testing.assert_array_equal(s.tau_env, [0.0, 0.0, 0.0])
    assert s.wave_elevation_m == 0.0


def test_a_seed_fixes_the_realisation_and_components_are_independent() -> None:
    cfg = EnvironmentConfig(waves=SEA, wind=WindConfig(speed_m_s=8.0, gust_std_m_s=1.0))
    x = np.array([10.0, -5.0, 0.4, 0.2, 0.0, 0.01])
    a, b = Environment(cfg, HULL, seed=7), Environment(cfg, HULL, seed=7)
    c = Environment(cfg, HULL, seed=8)
    np.testing.assert_array_equal(a.sample(33.0, x).tau_env, b.sample(33.0, x).tau_env)
    assert not np.allclose(a.sample(33.0, x).tau_env, c.sample(33.0, x).tau_env)
    waves_only = Environment(EnvironmentConfig(waves=SEA), HULL, seed=7)
    np.testing.assert_array_equal(waves_only.wave_wrench(33.0, x), a.wave_wrench(33.0, x))


def test_pierson_moskowitz_integrates_to_hs_squared_over_16() -> None:
    w = np.linspace(0.05, 20.0, 400_001)
    m0 = np.trapezoid(jonswap(w, 3.0, 9.0, gamma=1.0), w)
    assert m0 == pytest.approx(3.0**2 / 16.0, rel=1e-3)
    s = jonswap(w, 3.0, 9.0, gamma=3.3)
    assert w[np.argmax(s)] == pytest.approx(2.0 * math.pi / 9.0, rel=1e-3)
    assert np.trapezoid(s, w) == pytest.approx(3.0**2 / 16.0, rel=0.02)  # DNV's A_gamma


def test_wave_elevation_and_force_variance_match_the_spectrum() -> None:
    """Over 40 000 s the sampled variances equal the spectrum's integrals within 4 %:
    sigma_zeta^2 = int S dw (~ Hs^2 / 16) and sigma_F^2 = int S |F(w)|^2 dw per axis."""
    env = Environment(EnvironmentConfig(waves=SEA), HULL, seed=3)
    x = np.array([0.0, 0.0, math.radians(-10.0), 0.0, 0.0, 0.0])
    zeta = long_run(lambda t: env.wave_elevation(t, x), 40_000.0, 0.25)
    force = long_run(lambda t: env.wave_wrench(t, x), 40_000.0, 0.25)
    wp = 2.0 * math.pi / SEA.tp_s
    w = np.linspace(SEA.omega_lo * wp, SEA.omega_hi * wp, 20_001)
    s = jonswap(w, SEA.hs_m, SEA.tp_s, SEA.gamma)
    assert zeta.var() == pytest.approx(np.trapezoid(s, w), rel=0.04)
    assert zeta.var() == pytest.approx(SEA.hs_m**2 / 16.0, rel=0.05)
    h = froude_krylov(w**2 / 9.81, SEA.direction_rad - x[2], HULL)
    expected = np.trapezoid(s[:, None] * np.abs(h) ** 2, w, axis=0)
    np.testing.assert_allclose(force.var(axis=0), expected, rtol=0.04)
    assert abs(force.mean(axis=0)).max() < 0.05 * force.std(axis=0).min()  # first order: no mean


def _box_force_numerically(k: float, chi: float, hull: HullGeometry) -> np.ndarray:
    """-integral of p n dS over the four walls of the box, midpoint rule (independent check)."""
    n = 400
    z = (np.arange(n) + 0.5) / n * -hull.draft_m
    xs = (np.arange(n) + 0.5) / n * hull.l_oa_m - hull.l_oa_m / 2
    ys = (np.arange(n) + 0.5) / n * hull.beam_m - hull.beam_m / 2
    dz, dx, dy = hull.draft_m / n, hull.l_oa_m / n, hull.beam_m / n
    kx, ky = k * math.cos(chi), k * math.sin(chi)
    depth = np.exp(k * z).sum() * dz * 1025.0 * 9.81

    def p(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return depth * np.exp(-1j * (kx * x + ky * y))

    half_l, half_b = hull.l_oa_m / 2, hull.beam_m / 2
    fx = (p(-half_l, ys) - p(half_l, ys)).sum() * dy
    fy = (p(xs, -half_b) - p(xs, half_b)).sum() * dx
    n_z = (xs * (p(xs, -half_b) - p(xs, half_b))).sum() * dx
    n_z -= (ys * (p(-half_l, ys) - p(half_l, ys))).sum() * dy
    return np.array([fx, fy, n_z])


@pytest.mark.parametrize("chi_deg", [0.0, 30.0, 90.0, 135.0, -60.0])
@pytest.mark.parametrize("k", [0.02, 0.08, 0.3])
def test_froude_krylov_closed_form_equals_the_integrated_pressure(chi_deg: float, k: float) -> None:
    hull = HullGeometry(l_oa_m=76.2, beam_m=19.2, draft_m=6.0)
    closed = froude_krylov(np.array([k]), math.radians(chi_deg), hull)[0]
    numeric = _box_force_numerically(k, math.radians(chi_deg), hull)
    scale = np.abs(numeric).max()
    np.testing.assert_allclose(closed, numeric, rtol=0, atol=1e-4 * scale)


def test_froude_krylov_long_wave_limit_is_displaced_mass_times_acceleration() -> None:
    """k L -> 0 in head seas: |F_x| = C_B rho L B T w^2 per metre of amplitude (w^2 = g k)."""
    hull = HullGeometry(l_oa_m=76.2, beam_m=19.2, draft_m=6.0, block_coefficient=0.65)
    k = 1e-4
    f = froude_krylov(np.array([k]), 0.0, hull)[0]
    expected = 0.65 * 1025.0 * 76.2 * 19.2 * 6.0 * 9.81 * k
    assert abs(f[0]) == pytest.approx(expected, rel=1e-3)
    assert abs(f[1]) < 1e-9 * expected and abs(f[2]) < 1e-9 * expected * 76.2


def test_wind_on_the_bow_and_the_beam() -> None:
    c = WindCoefficients()
    v = 10.0
    q = 0.5 * RHO_AIR_KG_M3 * v * v
    head = wind_wrench(
        np.array([-v, 0.0]), AT_REST, c, HULL
    )  # blowing south onto a north-facing bow
    np.testing.assert_allclose(head, [-q * c.cd_l_bow * HULL.a_front_m2, 0.0, 0.0], atol=1e-9)
    # blowing west, i.e. from starboard of a north-facing vessel: pushes to port (-y)
    beam = wind_wrench(np.array([0.0, -v]), AT_REST, c, HULL)
    assert beam[1] == pytest.approx(-q * c.cd_t * HULL.a_lateral_m2, rel=1e-12)
    assert abs(beam[0]) < 1e-9 * abs(beam[1])
    # a vessel sailing with the wind at the wind's speed feels none
    sailing = np.array([0.0, 0.0, 0.0, v, 0.0, 0.0])
    np.testing.assert_allclose(wind_wrench(np.array([v, 0.0]), sailing, c, HULL), 0.0, atol=1e-12)


def test_wind_gust_statistics_match_their_configuration() -> None:
    cfg = EnvironmentConfig(
        wind=WindConfig(speed_m_s=10.0, gust_std_m_s=1.2, gust_time_constant_s=2.0)
    )
    env = Environment(cfg, HULL, seed=11)
    speed = long_run(env.wind_speed, 50_000.0, 0.1)
    assert speed.mean() == pytest.approx(10.0, abs=0.02 * 1.2)
    assert speed.std() == pytest.approx(1.2, rel=0.03)
    # correlated over the time constant, not white: lag-tau autocorrelation near e^-1
    lag = int(2.0 / 0.1)
    rho = np.corrcoef(speed[:-lag], speed[lag:])[0, 1]
    assert rho == pytest.approx(math.exp(-1.0), abs=0.05)


def test_current_statistics_and_direction() -> None:
    cfg = EnvironmentConfig(
        current=CurrentConfig(
            speed_m_s=0.5, direction_rad=math.radians(20.0), speed_std_m_s=0.05,
            direction_std_rad=math.radians(5.0), time_constant_s=3.0,
        )
    )  # fmt: skip
    env = Environment(cfg, HULL, seed=5)
    c = long_run(env.current_ned, 30_000.0, 0.15)
    speed, direction = np.hypot(c[:, 0], c[:, 1]), np.arctan2(c[:, 1], c[:, 0])
    assert speed.mean() == pytest.approx(0.5, abs=0.002)
    assert speed.std() == pytest.approx(0.05, rel=0.03)
    assert direction.mean() == pytest.approx(math.radians(20.0), abs=math.radians(0.2))
    assert direction.std() == pytest.approx(math.radians(5.0), rel=0.03)
    steady = Environment(EnvironmentConfig(current=CurrentConfig(0.3, math.pi / 2)), HULL)
    np.testing.assert_allclose(steady.current_ned(5.0), [0.0, 0.3], atol=1e-15)


def test_bad_levels_are_refused() -> None:
    with pytest.raises(ValueError, match="current.speed_m_s"):
        EnvironmentConfig(current=CurrentConfig(speed_m_s=-0.1))
    with pytest.raises(ValueError, match="waves.tp_s"):
        EnvironmentConfig(waves=WaveConfig(hs_m=1.0, tp_s=0.0))
    with pytest.raises(ValueError, match="a_front_m2"):
        Environment(EnvironmentConfig(wind=WindConfig(speed_m_s=5.0)), HullGeometry(10, 3, 1))


def test_the_force_factor_scales_each_axis() -> None:
    x = np.array([5.0, 1.0, 0.3, 0.0, 0.0, 0.0])
    plain = Environment(EnvironmentConfig(waves=SEA), HULL, seed=2)
    factored = WaveConfig(hs_m=SEA.hs_m, tp_s=SEA.tp_s, direction_rad=SEA.direction_rad,
                          force_factor=(2.0, 1.0, 0.5))  # fmt: skip
    env = Environment(EnvironmentConfig(waves=factored), HULL, seed=2)
    t = np.linspace(0.0, 100.0, 11)
    np.testing.assert_allclose(env.wave_wrench(t, x), plain.wave_wrench(t, x) * [2.0, 1.0, 0.5])


@pytest.mark.parametrize("psi_deg", [0.0, 30.0, 90.0, -120.0, 180.0])
def test_the_real_arithmetic_wave_wrench_equals_the_complex_form(psi_deg: float) -> None:
    env = Environment(EnvironmentConfig(waves=SEA), HULL, seed=9)
    waves = env.waves
    assert waves is not None
    x = np.array([12.0, -7.0, math.radians(psi_deg), 0.0, 0.0, 0.0])
    t = np.linspace(0.0, 60.0, 7)
    f = froude_krylov(waves.k_rad_m, waves.direction_rad - x[2], HULL) * waves.amplitude_m[:, None]
    expected = np.real(np.exp(1j * waves.phases(t, x)) @ f)
    got = env.wave_wrench(t, x)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
