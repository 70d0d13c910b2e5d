"""Vessel presets (ftcap_hil/data/vessels): they load, they are over-actuated, their numbers
are their sources' (spot checks, each with its citation), and the loader is strict."""

from __future__ import annotations

import dataclasses
import math
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from ftcap_hil.config.presets import apply_mismatch, load_preset, preset_names
from ftcap_hil.core.effectiveness.geometry import effectiveness
from ftcap_hil.core.errors import ConfigError
from sim.environment import Environment

FROUDE = math.sqrt(70.0)  # CyberShip II is a 1:70 model


def test_the_shipped_presets() -> None:
    assert {"cybership2", "supply"} <= set(preset_names())


@pytest.mark.parametrize("name", ["cybership2", "supply"])
def test_each_preset_is_over_actuated(name: str) -> None:
    p = load_preset(name)
    b = p.B
    assert b.shape[0] == 3 and b.shape[1] > 3
    singular = np.linalg.svd(b, compute_uv=False)
    assert np.linalg.matrix_rank(b) == 3 and singular.min() > 1e-3 * singular.max()
    null = np.linalg.svd(b)[2][3:]  # rows spanning the null space
    assert null.shape[0] == b.shape[1] - 3
    np.testing.assert_allclose(b @ null.T, 0.0, atol=1e-12)
    assert p.time_constants_s.shape == (b.shape[1],) and np.all(p.time_constants_s > 0)
    assert np.all(p.thrusters.u_min < 0) and np.all(p.thrusters.u_max > 0)


def test_cybership2_numbers_are_skjetne_smogeli_fossen_2004() -> None:
    """Skjetne, Smogeli & Fossen (2004), MIC 25(1), Tables 1, 2 and 4."""
    v = load_preset("cybership2").vessel
    assert (v.mass_kg, v.iz_kgm2, v.xg_m) == (23.8, 1.76, 0.046)  # Table 1
    assert (v.X_udot, v.Y_vdot, v.Y_rdot, v.N_vdot, v.N_rdot) == (-2.0, -10.0, 0.0, 0.0, -1.0)
    assert (v.X_u, v.X_uu, v.X_uuu) == (-0.72253, -1.32742, -5.86643)  # Table 2
    assert (v.Y_v, v.Y_vv, v.N_v, v.N_vv) == (-0.88965, -36.47287, 0.03130, 3.95645)
    assert (v.Y_r, v.Y_rv, v.Y_vr, v.Y_rr) == (-7.25, -0.805, -0.845, -3.45)  # Table 4
    assert (v.N_r, v.N_rv, v.N_vr, v.N_rr) == (-1.9, 0.13, 0.08, -0.75)
    np.testing.assert_allclose(v.mass_matrix, [[25.8, 0, 0], [0, 33.8, 1.0948], [0, 1.0948, 2.76]])


def test_cybership2_actuators() -> None:
    """Table 1 positions; thrust T+|n|n = 3.65034e-3, T-|n|n = 5.10256e-3 (Table 2) and the
    bow's 1.56822e-4 N/rps^2 at the assumed 2000 rpm; MSS initCS2.m's 5-column layout."""
    p = load_preset("cybership2")
    t = {th.name: th for th in p.thrusters.thrusters}
    n2 = (2000.0 / 60.0) ** 2
    assert (t["port_propeller"].x_m, t["port_propeller"].y_m) == (-0.499, -0.078)
    assert (t["starboard_propeller"].x_m, t["starboard_propeller"].y_m) == (-0.499, 0.078)
    assert (t["bow_tunnel"].x_m, t["bow_tunnel"].y_m) == (0.466, 0.0)
    assert t["port_propeller"].u_max == pytest.approx(3.65034e-3 * n2, rel=1e-12)
    assert t["port_propeller"].u_min == pytest.approx(-5.10256e-3 * n2, rel=1e-12)
    assert t["bow_tunnel"].u_max == pytest.approx(1.56822e-4 * n2, rel=1e-12)
    # [T1 T2 in surge; T3 R1 R2 in sway], yaw arms -y for surge, x for sway
    order = ["port_propeller", "starboard_propeller", "bow_tunnel", "port_rudder"]
    order += ["starboard_rudder"]
    b = effectiveness(p.thrusters)[:, [p.thrusters.names.index(n) for n in order]]
    expected = [[1, 1, 0, 0, 0], [0, 0, 1, 1, 1], [0.078, -0.078, 0.466, -0.549, -0.549]]
    np.testing.assert_allclose(b, expected, atol=1e-15)


# Fossen's supply vessel (PythonVehicleSimulator supply.py; MSS supply.m): bis-scaled matrices
M_BIS = np.array([[1.1274, 0, 0], [0, 1.8902, -0.0744], [0, -0.0744, 0.1278]])
D_BIS = np.array([[0.0358, 0, 0], [0, 0.1183, -0.0124], [0, -0.0041, 0.0308]])
MASS, LENGTH, G = 6000.0e3, 76.2, 9.81
T_INV = np.diag([1.0, 1.0, LENGTH])


def test_supply_matrices_are_fossens() -> None:
    """M3 = m Tinv Mbis Tinv and D3 = m sqrt(g/L) Tinv Dbis Tinv (supply.py)."""
    v = load_preset("supply").vessel
    np.testing.assert_allclose(v.mass_matrix, MASS * T_INV @ M_BIS @ T_INV, rtol=1e-12)
    d3 = MASS * math.sqrt(G / LENGTH) * T_INV @ D_BIS @ T_INV
    d_model = -np.array([[v.X_u, 0, 0], [0, v.Y_v, v.Y_r], [0, v.N_v, v.N_r]])
    np.testing.assert_allclose(d_model, d3, rtol=1e-12)
    assert (v.X_uu, v.Y_vv, v.N_rr) == (0.0, 0.0, 0.0)  # a linear DP model


def test_supply_without_coriolis_is_fossens_dp_model_in_a_current() -> None:
    """nu_dot = M3^-1 (tau - D3 nu_r), nu_r = nu - [V cos(beta - psi), V sin(beta - psi), 0]."""
    v = dataclasses.replace(load_preset("supply").vessel, coriolis=False)
    m3 = MASS * T_INV @ M_BIS @ T_INV
    d3 = MASS * math.sqrt(G / LENGTH) * T_INV @ D_BIS @ T_INV
    psi, speed, beta = 0.7, 0.5, math.radians(20.0)
    nu, tau = np.array([0.3, -0.1, 0.004]), np.array([2e5, -1e5, 3e6])
    nu_c = np.array([speed * math.cos(beta - psi), speed * math.sin(beta - psi), 0.0])
    expected = np.linalg.solve(m3, tau - d3 @ (nu - nu_c))
    current = np.array([speed * math.cos(beta), speed * math.sin(beta)])
    got = v.nu_dot(nu, tau, v.current_body(psi, current))
    # the only extra term is M_A nu_c_dot (the current seen rotating with the vessel)
    nu_c_dot = nu[2] * np.array([nu_c[1], -nu_c[0], 0.0])
    np.testing.assert_allclose(got, expected + np.linalg.solve(m3, v.added_mass @ nu_c_dot))


def test_supply_thrusters_are_fossens() -> None:
    """B diag(u_max) = T K diag(n_max^2), T = [[0,0,0,0,1,1],[1,1,1,1,0,0],
    [30,22,-22,-30,-8,8]], K = diag(3.2 x 4, 31.2 x 2), n_max = 250 / 160 RPM (supply.py)."""
    p = load_preset("supply")
    t = np.array([[0, 0, 0, 0, 1, 1], [1, 1, 1, 1, 0, 0], [30, 22, -22, -30, -8, 8]], float)
    k = np.diag([3.2, 3.2, 3.2, 3.2, 31.2, 31.2])
    n_max = np.array([250, 250, 250, 250, 160, 160], float)
    np.testing.assert_allclose(
        p.B @ np.diag(p.thrusters.u_max), t @ k @ np.diag(n_max**2), rtol=1e-12, atol=1e-6
    )  # atol: cos(90 deg) is 6e-17, not 0
    np.testing.assert_array_equal(p.time_constants_s, 1.0)  # T_n


def test_supply_environment_levels_and_cybership2_is_their_froude_scaling() -> None:
    s, c = load_preset("supply"), load_preset("cybership2")
    cur = s.environment.current
    assert (cur.speed_m_s, math.degrees(cur.direction_rad)) == (0.5, 20.0)  # MSS SIMsupply.m
    assert s.environment.waves.hs_m == pytest.approx(0.21 * 10.0**2 / 9.81)  # MSS vw2hs.m
    assert c.environment.current.speed_m_s == pytest.approx(cur.speed_m_s / FROUDE)
    assert c.environment.current.time_constant_s == pytest.approx(cur.time_constant_s / FROUDE)
    assert c.environment.wind.speed_m_s == pytest.approx(s.environment.wind.speed_m_s / FROUDE)
    assert c.environment.waves.hs_m == pytest.approx(s.environment.waves.hs_m / 70.0)
    assert c.environment.waves.tp_s == pytest.approx(s.environment.waves.tp_s / FROUDE)
    assert s.sensors.position_std_m == 0.01
    assert s.sensors.heading_std_rad == pytest.approx(math.radians(0.1))


@pytest.mark.parametrize("name", ["cybership2", "supply"])
def test_a_preset_drifts_plausibly_in_its_own_environment(name: str) -> None:
    """60 s of no thrust in the preset's conditions: finite, carried roughly downstream."""
    p = load_preset(name)
    env = Environment(p.environment, p.hull)
    dt = 0.05 if name == "cybership2" else 0.5
    x = np.zeros(6)
    for k in range(int(60.0 / dt)):
        s = env.sample(k * dt, x)
        x = p.vessel.step_rk4(x, np.zeros(3), dt, 4, s.current_ned, s.tau_env)
    assert np.all(np.isfinite(x))
    drift = x[:2] / np.linalg.norm(x[:2])
    current = env.current_ned(0.0) / np.linalg.norm(env.current_ned(0.0))
    assert drift @ current > 0.5


def test_no_mismatch_gives_the_truth_and_a_mismatch_changes_what_it_says() -> None:
    p = load_preset("cybership2")
    same = apply_mismatch(p)
    assert same.vessel == p.vessel
    np.testing.assert_array_equal(same.B, p.B)
    m = apply_mismatch(
        p, mass=0.2, damping=-0.3, angle_deg={2: 5.0}, position_m={"bow_tunnel": (0.01, 0.0)}
    )
    np.testing.assert_allclose(m.vessel.mass_matrix, 1.2 * p.vessel.mass_matrix, rtol=1e-14)
    nu = np.array([0.2, -0.1, 0.05])
    np.testing.assert_allclose(m.vessel.damping(nu), 0.7 * p.vessel.damping(nu), rtol=1e-14)
    turned = m.thrusters.thrusters[2]
    assert turned.angle_rad == pytest.approx(p.thrusters.thrusters[2].angle_rad + math.radians(5))
    assert m.thrusters.thrusters[4].x_m == pytest.approx(0.476)
    np.testing.assert_array_equal(np.delete(m.B, [2, 4], axis=1), np.delete(p.B, [2, 4], axis=1))
    with pytest.raises(ConfigError, match="did you mean 'bow_tunnel'"):
        apply_mismatch(p, angle_deg={"bow_tunel": 1.0})


def _write(tmp_path: Path, old: str, new: str) -> Path:
    text = resources.files("ftcap_hil.data.vessels").joinpath("supply.toml").read_text()
    assert old in text
    path = tmp_path / "vessel.toml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("[damping]", "[dampng]", r"\[damping\] missing \('dampng' is given: a typo\?\)"),
        ("X_u = ", "X_uh = ", r"\[damping\] unknown key 'X_uh' \(did you mean 'X_u'"),
        ("u_max = 200000.0", "u_mx = 200000.0", r"\[\[thruster\]\]\[0\] u_max: missing \('u_mx'"),
        ("hs_m = ", "hs = ", r"\[environment\.waves\] unknown key 'hs' \(did you mean 'hs_m'\?\)"),
        (
            "mass = 0.0",
            "mass = 'heavy'",
            r"\[mismatch\] mass: expected a finite number, got",
        ),
        ("angle_deg = {}", "angle_deg = { bow_tunel_1 = 2.0 }", r"did you mean 'bow_tunnel_1'"),
        ("speed_m_s = 0.5", "speed_m_s = -0.5", r"current\.speed_m_s: must be finite and >= 0"),
        (
            'drive = "speed"',
            'drive = "sped"',
            r"\[0\] drive: 'sped' is not one of 'speed', 'torque'",
        ),
        (
            "diameter_m = 2.5",
            "diameter = 2.5",
            r"diameter_m: missing \('diameter' is given",
        ),
        ("rate_hz = 2.0", "rate = 2.0", r"\[telemetry\] unknown key 'rate'"),
        (
            "telemetry_timeout_s = 2.5",
            "telemetry_timeout = 2.5",
            r"\[diagnosis\] unknown key 'telemetry_timeout'",
        ),
    ],
)
def test_a_bad_preset_names_its_file_table_and_key(
    tmp_path: Path, old: str, new: str, message: str
) -> None:
    path = _write(tmp_path, old, new)
    with pytest.raises(ConfigError, match=message) as err:
        load_preset(path)
    assert str(path) in str(err.value)


def test_a_stated_mismatch_is_read_and_overrides_apply() -> None:
    calm_air = ["environment.wind.speed_m_s=0", "environment.wind.gust_std_m_s=0"]
    p = load_preset("supply", overrides=["mismatch.mass=0.2", *calm_air])
    assert p.mismatch.mass == 0.2 and not p.environment.wind.enabled
    model = apply_mismatch(p)
    assert model.vessel.mass_kg == pytest.approx(1.2 * 6.0e6)


def test_the_presets_drives_and_their_data_sheet() -> None:
    """CyberShip II: 60 mm propellers at K_T 0.2816 in fresh water give [SSF04]'s 3.65e-3
    N/rps^2; rudders are servos; the supply vessel reports at 2 Hz."""
    from ftcap_hil.config.drives import data_sheet
    from sim.shaft import Propeller, Servo

    cs2 = load_preset("cybership2")
    assert cs2.drives is not None
    prop, rudder = cs2.drives.actuators[0], cs2.drives.actuators[2]
    assert isinstance(prop, Propeller) and isinstance(rudder, Servo)
    assert prop.k_t * prop.rho_kgm3 * prop.diameter_m**4 == pytest.approx(3.65e-3, rel=1e-3)
    full = np.maximum(np.abs(cs2.thrusters.u_min), np.abs(cs2.thrusters.u_max))
    sheet = data_sheet(cs2.drives.actuators, full, cs2.time_constants_s)
    assert sheet[0].k_thrust == pytest.approx(3.65e-3, rel=1e-3) and not sheet[2].is_shaft
    supply = load_preset("supply")
    assert supply.drives is not None and supply.drives.feedback.rate_hz == 2.0
    assert supply.diagnosis["latency_s"] == 0.2


def test_a_drive_on_some_thrusters_only_is_an_error(tmp_path: Path) -> None:
    text = resources.files("ftcap_hil.data.vessels").joinpath("supply.toml").read_text()
    path = tmp_path / "vessel.toml"
    path.write_text(text.replace('drive = "speed"', "", 1))
    with pytest.raises(ConfigError, match="every thruster needs a drive once one has"):
        load_preset(path)
