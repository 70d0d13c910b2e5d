"""Six degrees of freedom: thruster geometry -> B (6 x m), the allocation's limits and reach
on random geometries, the BlueROV2 Heavy's file, and the rigid body's physics."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ftcap_hil.config.underwater import load_vehicle, vehicle_names
from ftcap_hil.config.vessel import thrusters_from_table
from ftcap_hil.core.allocation.allocator import Allocator, AllocatorConfig
from ftcap_hil.core.effectiveness.geometry import (
    Thruster,
    ThrusterSet,
    command_bounds,
    effectiveness,
)
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.estimation.config import wrench_scale
from ftcap_hil.core.models.vehicle6dof import Vehicle6DOF, rotation

ROV = load_vehicle("bluerov2-heavy")
finite = st.floats(-2.0, 2.0, allow_nan=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False)


# ---------------------------------------------------------------- geometry


@settings(max_examples=200, deadline=None)
@given(x=finite, y=finite, a=angle)
def test_a_thruster_in_the_plane_is_its_3dof_column_in_6dof(x: float, y: float, a: float) -> None:
    th = Thruster("t", x, y, a, -1.0, 1.0)
    col3, col6 = th.column(), th.column6()
    np.testing.assert_allclose(col6[[0, 1, 5]], col3, rtol=0, atol=1e-15)
    np.testing.assert_allclose(col6[[2, 3, 4]], 0.0, rtol=0, atol=1e-15)


@settings(max_examples=200, deadline=None)
@given(x=finite, y=finite, z=finite, a=angle, e=st.floats(-math.pi / 2, math.pi / 2))
def test_the_6dof_column_is_force_and_moment(
    x: float, y: float, z: float, a: float, e: float
) -> None:
    col = Thruster("t", x, y, a, -1.0, 1.0, z_m=z, elevation_rad=e).column6()
    d = col[:3]
    assert np.linalg.norm(d) == pytest.approx(1.0, abs=1e-12)
    # moment = r x d, written out component by component
    r = (x, y, z)
    moment = [r[1] * d[2] - r[2] * d[1], r[2] * d[0] - r[0] * d[2], r[0] * d[1] - r[1] * d[0]]
    np.testing.assert_allclose(col[3:], moment, rtol=0, atol=1e-12)
    assert float(d @ col[3:]) == pytest.approx(0.0, abs=1e-12)  # a pure force: moment _|_ d


def test_columns_by_hand() -> None:
    # pushing up (elevation -90 deg) at 0.2 m forward, 0.3 m to starboard: Z -1, roll -0.3
    # (starboard lifted), pitch +0.2 (bow lifted)
    up = Thruster("v", 0.2, 0.3, 0.0, -1.0, 1.0, z_m=-0.05, elevation_rad=-math.pi / 2)
    np.testing.assert_allclose(up.column6(), [0, 0, -1, -0.3, 0.2, 0], rtol=0, atol=1e-15)
    # pushing ahead 0.1 m below the origin: surge with a bow-down moment -0.1 ... M = z * X
    low = Thruster("h", 0.0, 0.0, 0.0, -1.0, 1.0, z_m=0.1)
    np.testing.assert_allclose(low.column6(), [1, 0, 0, 0, 0.1, 0], rtol=0, atol=1e-15)


def test_direction_vector_equals_angle_and_elevation() -> None:
    base = {"name": "t", "x": 0.2, "y": -0.1, "z": 0.05, "u_min": -1.0, "u_max": 1.0}
    by_dir = thrusters_from_table(
        {"dofs": 6, "thruster": [{**base, "direction": [1.0, 1.0, -math.sqrt(2.0)]}]}
    )
    by_angle = thrusters_from_table(
        {"dofs": 6, "thruster": [{**base, "angle_deg": 45.0, "elevation_deg": -45.0}]}
    )
    np.testing.assert_allclose(effectiveness(by_dir), effectiveness(by_angle), atol=1e-12)
    assert effectiveness(by_dir).shape == (6, 1)


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"dofs": 4}, "[vessel] dofs: expected 3 (X, Y, N) or 6"),
        ({"thruster_extra": 1}, "[vessel] unknown key 'thruster_extra'"),
        ({"elevation_deg": 120.0}, "elevation_deg"),
        ({"direction": [1.0, 0.0, 0.0, 1.0]}, "direction: expected [dx, dy] or [dx, dy, dz]"),
    ],
)
def test_bad_6dof_keys_are_named(table: dict[str, object], message: str) -> None:
    entry: dict[str, object] = {"x": 0.0, "y": 0.0, "u_min": -1.0, "u_max": 1.0}
    doc: dict[str, object] = {"dofs": 6, "thruster": [entry]}
    if "direction" in table:
        entry["direction"] = table["direction"]
    else:
        entry["angle_deg"] = 0.0
        if "elevation_deg" in table:
            entry["elevation_deg"] = table["elevation_deg"]
        else:
            doc.update(table)
    with pytest.raises(ConfigError, match=re.escape(message)):
        thrusters_from_table(doc)


def test_a_6dof_vessel_table_is_refused_by_the_surface_plant() -> None:
    from ftcap_hil.config.tables import Table
    from ftcap_hil.config.vessel import plant_from

    doc = {
        "plant": {"kind": "vessel", "mass_kg": 1.0, "iz_kgm2": 1.0},
        "vessel": {
            "dofs": 6,
            "thruster": [{"x": 0, "y": 0, "angle_deg": 0, "u_min": -1, "u_max": 1}],
        },
    }
    with pytest.raises(ConfigError, match=re.escape("[vessel] dofs: the surface-vessel plant")):
        with Table(doc, "f.toml", "") as root:
            plant_from(root)


# ---------------------------------------------------------------- allocation in 6 DOF


@st.composite
def geometry(draw: st.DrawFn) -> tuple[ThrusterSet, np.ndarray]:
    """A random vehicle of 6-10 thrusters whose B (6 x m) has full rank, condition <= 20 (the
    QP's slack weight meets a demand to ~1e-6 / sigma_min^2 of the axis scale: a vehicle
    near a singular layout is met less exactly, as it should be)."""
    m = draw(st.integers(6, 10))
    ths = []
    for i in range(m):
        lo = -draw(st.floats(0.2, 2.0))
        hi = draw(st.floats(0.2, 2.0))
        ths.append(
            Thruster(
                f"T{i}", draw(finite), draw(finite), draw(angle), lo, hi,
                rate_max=draw(st.one_of(st.none(), st.floats(0.5, 20.0))),
                z_m=draw(finite), elevation_rad=draw(st.floats(-math.pi / 2, math.pi / 2)),
            )
        )  # fmt: skip
    th_set = ThrusterSet(tuple(ths), dofs=6)
    B = effectiveness(th_set)
    s = np.linalg.svd(B, compute_uv=False)
    if s[-1] < 0.05 * s[0]:
        from hypothesis import reject

        reject()
    return th_set, B


@settings(max_examples=150, deadline=None)
@given(g=geometry(), data=st.data())
def test_6dof_allocation_holds_the_limits_and_meets_what_is_attainable(
    g: tuple[ThrusterSet, np.ndarray], data: st.DataObject
) -> None:
    ths, B = g
    m, dt = ths.m, 0.1
    step = ths.max_step(dt)
    u_prev = ths.u_min + np.array(data.draw(st.lists(st.floats(0, 1), min_size=m, max_size=m))) * (
        ths.u_max - ths.u_min
    )
    lo, hi = command_bounds(ths.u_min, ths.u_max, step, u_prev)
    alloc = Allocator(B, ths, dt, wrench_scale(B, ths.u_min, ths.u_max), AllocatorConfig())
    # an attainable demand: a command inside this cycle's box
    frac = np.array(data.draw(st.lists(st.floats(0, 1), min_size=m, max_size=m)))
    tau = B @ (lo + frac * (hi - lo))
    res = alloc.allocate(tau, np.ones(m), np.zeros(6), u_prev)
    assert np.all(res.u >= lo - 1e-9) and np.all(res.u <= hi + 1e-9)
    scale = wrench_scale(B, ths.u_min, ths.u_max)
    assert np.all(np.abs(res.unallocated) <= 1e-3 * scale), res.unallocated / scale
    # an unattainable one still gets a command inside the box, finite
    res = alloc.allocate(tau * 50.0 + scale, np.ones(m), np.zeros(6), u_prev)
    assert np.all(np.isfinite(res.u))
    assert np.all(res.u >= lo - 1e-9) and np.all(res.u <= hi + 1e-9)


def test_the_qp_meets_attainable_demands_the_pseudo_inverse_misses() -> None:
    rng = np.random.default_rng(20261207)
    ths, B = ROV.thrusters, ROV.B
    scale = wrench_scale(B, ths.u_min, ths.u_max)
    alloc = Allocator(B, ths, 0.1, scale, AllocatorConfig())
    pinv = np.linalg.pinv(B)
    missed_by_pinv = 0
    for _ in range(400):
        u_star = ths.u_min + rng.uniform(0.0, 1.0, ths.m) * (ths.u_max - ths.u_min)
        tau = B @ u_star
        clipped = np.clip(pinv @ tau, ths.u_min, ths.u_max)
        if np.abs(B @ clipped - tau).max() > 1e-3 * scale.min():
            missed_by_pinv += 1
        res = alloc.allocate(tau, np.ones(ths.m), np.zeros(6), np.zeros(ths.m))
        assert np.all(np.abs(res.unallocated) <= 1e-4 * scale)
    # the test has power: the clipped pseudo-inverse misses a good share of these demands
    assert missed_by_pinv >= 40, missed_by_pinv


# ---------------------------------------------------------------- the BlueROV2 Heavy


def test_the_shipped_rov_is_found_and_fully_actuated() -> None:
    assert "bluerov2-heavy" in vehicle_names()
    B = ROV.B
    assert B.shape == (6, 8)
    assert np.linalg.matrix_rank(B) == 6
    # horizontal thrusters give X, Y, N; vertical ones Z, K, M (each group full rank in its 3)
    assert np.linalg.matrix_rank(B[np.ix_([0, 1, 5], range(4))]) == 3
    assert np.linalg.matrix_rank(B[np.ix_([2, 3, 4], range(4, 8))]) == 3
    np.testing.assert_allclose(B[2, 4:], -1.0)  # the vertical ones push up


@pytest.mark.parametrize("dead", range(8))
def test_the_rov_hovers_and_surges_with_any_one_thruster_dead(dead: int) -> None:
    ths, B = ROV.thrusters, ROV.B
    scale = wrench_scale(B, ths.u_min, ths.u_max)
    alloc = Allocator(B, ths, 0.1, scale, AllocatorConfig())
    hover = ROV.body.restoring(np.zeros(6))  # what holds it level at rest
    tau = hover + np.array([10.0, 0.0, 0.0, 0.0, 0.0, 0.5])  # 10 N ahead, 0.5 N m of yaw
    delta = np.ones(8)
    delta[dead] = 0.0
    res = alloc.allocate(tau, delta, np.zeros(6), np.zeros(8))
    assert res.u[dead] == 0.0
    np.testing.assert_allclose(res.unallocated, 0.0, atol=1e-3)


def test_an_unknown_key_in_the_vehicle_file_is_named() -> None:
    with pytest.raises(ConfigError, match=re.escape("[rigid_body] unknown key 'mass'")):
        load_vehicle("bluerov2-heavy", ["rigid_body.mass=3"])


# ---------------------------------------------------------------- the rigid body


def test_coriolis_does_no_work_and_damping_only_dissipates() -> None:
    rng = np.random.default_rng(3)
    body = ROV.body
    for _ in range(50):
        nu = rng.normal(0.0, 0.5, 6)
        assert float(nu @ body.coriolis(nu, nu)) == pytest.approx(0.0, abs=1e-12)
        assert float(nu @ body.damping(nu)) >= 0.0


def test_at_rest_and_level_only_the_net_weight_acts() -> None:
    body = ROV.body
    g = body.restoring(np.zeros(6))
    np.testing.assert_allclose(g, [0, 0, -(body.weight_n - body.buoyancy_n), 0, 0, 0], atol=1e-12)
    x = np.zeros(12)
    for _ in range(100):  # 1 s, no thrust: it sinks slowly (0.98 N heavy in fresh water)
        x = ROV.body.step_rk4(x, np.zeros(6), 0.01)
    assert 0.0 < x[2] < 0.05 and np.abs(x[[0, 1, 3, 4, 5]]).max() < 1e-12


def test_buoyancy_above_gravity_rights_a_pitched_rov() -> None:
    x = np.zeros(12)
    x[4] = 0.3  # bow up 0.3 rad
    assert ROV.body.restoring(x[:6])[4] > 0.0  # on the left side: a bow-down moment
    peak = 0.0
    for _ in range(3000):  # 30 s
        x = ROV.body.step_rk4(x, -ROV.body.restoring(np.zeros(6)), 0.01)
        peak = max(peak, abs(x[4])) if _ > 500 else peak
    assert abs(x[4]) < 0.05 and peak < 0.3


def test_steady_surge_is_where_thrust_meets_drag() -> None:
    body = ROV.body
    thrust = 40.0
    lin, quad = body.damping_linear[0], body.damping_quadratic[0]
    u_ss = (-lin + math.sqrt(lin**2 + 4.0 * quad * thrust)) / (2.0 * quad)
    x = np.zeros(12)
    tau = body.restoring(np.zeros(6)) + np.array([thrust, 0, 0, 0, 0, 0])
    for _ in range(2000):  # 20 s at 0.01 s
        x = body.step_rk4(x, tau, 0.01)
    assert x[6] == pytest.approx(u_ss, rel=1e-3)
    assert x[0] == pytest.approx(x[6] * 20.0, rel=0.15)  # it got there early


def test_a_current_is_felt_through_the_relative_velocity() -> None:
    body = ROV.body
    x = np.zeros(12)
    x[5] = math.pi / 2  # heading east
    hold = body.restoring(np.zeros(6))
    for _ in range(3000):  # 30 s in a 0.3 m/s current to the north
        x = body.step_rk4(x, hold, 0.01, np.array([0.3, 0.0, 0.0]))
    # drifts north with the water: in body axes that is to port (heading east)
    assert x[0] > 5.0 and abs(x[1]) < 0.2
    v_ned = rotation(*x[3:6]) @ x[6:9]
    assert v_ned[0] == pytest.approx(0.3, abs=0.01)


def test_the_float_derivative_is_the_reference_one() -> None:
    rng = np.random.default_rng(11)
    lopsided = Vehicle6DOF(
        mass_kg=20.0, volume_m3=0.021, inertia_kgm2=(0.4, 0.9, 1.1), cb_m=(0.02, -0.01, -0.03),
        added_mass=(3.0, 9.0, 14.0, 0.1, 0.3, 0.2), damping_linear=(5.0, 6.0, 7.0, 0.1, 0.2, 0.3),
        damping_quadratic=(50.0, 80.0, 90.0, 1.0, 2.0, 3.0),
    )  # fmt: skip
    for body in (ROV.body, lopsided):
        for _ in range(300):
            x = rng.normal(0.0, 0.5, 12)
            x[4] = rng.uniform(-1.2, 1.2)
            tau = rng.normal(0.0, 20.0, 6)
            for current in (None, rng.normal(0.0, 0.5, 3)):
                np.testing.assert_allclose(
                    body.derivative(x, tau, current),
                    body.derivative_reference(x, tau, current),
                    rtol=1e-12, atol=1e-12,
                )  # fmt: skip


def test_bad_numbers_are_refused() -> None:
    kwargs = dict(
        mass_kg=1.0, volume_m3=0.001, inertia_kgm2=(1.0, 1.0, 1.0), cb_m=(0.0, 0.0, 0.0),
        added_mass=(0.0,) * 6, damping_linear=(0.0,) * 6, damping_quadratic=(0.0,) * 6,
    )  # fmt: skip
    Vehicle6DOF(**kwargs)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="added_mass"):
        Vehicle6DOF(**{**kwargs, "added_mass": (1.0,) * 5})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="cg_m"):
        Vehicle6DOF(**{**kwargs, "cg_m": (0.0, 0.0, 0.01)})  # type: ignore[arg-type]
