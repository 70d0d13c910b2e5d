"""Plant models: the wrench inversion undoes a step, damping dissipates, angles wrap."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ftcap_hil.core.models.controllers import PoseController, StateFeedback
from ftcap_hil.core.models.plants import Inversion, LinearPlant, SurfaceVessel, wrap_angle


def vec(n: int, bound: float) -> st.SearchStrategy[np.ndarray]:
    return st.lists(st.floats(-bound, bound), min_size=n, max_size=n).map(np.array)


@settings(max_examples=100, deadline=None)
@given(
    a=st.floats(-2.0, 2.0),
    b_v=st.floats(0.1, 5.0),
    x=st.floats(-100.0, 100.0),
    tau=st.floats(-100.0, 100.0),
)
def test_linear_inverts_step(a: float, b_v: float, x: float, tau: float) -> None:
    plant = LinearPlant(a=a, b_v=b_v)
    x1 = plant.step(np.array([x]), np.array([tau]), 1.0)
    w = plant.measured_wrench(np.array([x]), x1, 1.0)
    assert w.shape == (1,)
    assert w[0] == pytest.approx(tau, rel=1e-12, abs=1e-12 * (abs(a * x) + abs(tau)) / b_v + 1e-300)


def test_linear_paper_numbers() -> None:
    plant = LinearPlant()
    np.testing.assert_array_equal(plant.step(np.array([1.0]), np.array([0.5]), 1.0), [1.7])


@settings(max_examples=100, deadline=None)
@given(eta=vec(3, 10.0), nu=vec(3, 2.0), tau=vec(3, 5.0), dt=st.floats(0.01, 1.0))
def test_vessel_euler_inversion_undoes_step(
    eta: np.ndarray, nu: np.ndarray, tau: np.ndarray, dt: float
) -> None:
    vessel = SurfaceVessel(inversion=Inversion.EULER)
    x0 = np.concatenate([eta, nu])
    x1 = vessel.step(x0, tau, dt)
    w = vessel.measured_wrench(x0, x1, dt)
    np.testing.assert_allclose(w, tau, rtol=0, atol=1e-10)


def test_vessel_trapezoid_is_second_order_against_rk4() -> None:
    """Against an RK4 truth the trapezoid inversion is (much) closer than Euler's."""
    x0 = np.array([0.0, 0.0, 0.3, 0.5, -0.2, 0.1])
    tau = np.array([0.1, -0.05, 0.02])
    dt = 0.2827
    errors = {}
    for inversion in Inversion:
        vessel = SurfaceVessel(inversion=inversion)
        x1 = vessel.step_rk4(x0, tau, dt, substeps=16)
        errors[inversion] = np.abs(vessel.measured_wrench(x0, x1, dt) - tau).max()
    assert errors[Inversion.TRAPEZOID] < errors[Inversion.EULER] / 10


def test_vessel_rejects_unknown_inversion() -> None:
    with pytest.raises(ValueError, match="inversion.*'midpoint'"):
        SurfaceVessel(inversion="midpoint")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="expected Inversion"):  # the enum, not its spelling
        SurfaceVessel(inversion="euler")  # type: ignore[arg-type]


@settings(max_examples=100, deadline=None)
@given(nu=vec(3, 10.0))
def test_damping_is_dissipative_and_coriolis_does_no_work(nu: np.ndarray) -> None:
    vessel = SurfaceVessel()
    power = float(nu @ vessel.drag_and_coriolis(nu))
    expected = (
        vessel.beta_u * abs(nu[0]) ** 3
        + vessel.beta_v * abs(nu[1]) ** 3
        + vessel.beta_r * abs(nu[2]) ** 3
    )
    assert power >= -1e-12 * (1 + np.abs(nu).max() ** 3)
    assert power == pytest.approx(expected, rel=1e-9, abs=1e-9)
    coriolis_only = SurfaceVessel(beta_u=0.0, beta_v=0.0, beta_r=0.0)
    work = float(nu @ coriolis_only.drag_and_coriolis(nu))
    assert abs(work) <= 1e-12 * (1 + np.abs(nu).max() ** 3)


def test_damping_opposes_motion_in_every_direction() -> None:
    """The paper's D = diag(beta u, ...) would push a reversing vessel; ours brakes it."""
    vessel = SurfaceVessel()
    for nu in ([-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]):
        force = vessel.drag_and_coriolis(np.array(nu))
        assert float(np.dot(force, nu)) > 0.0


@settings(max_examples=200, deadline=None)
@given(a=st.floats(-1e4, 1e4))
def test_wrap_angle_range(a: float) -> None:
    w = float(wrap_angle(a))
    assert -math.pi < w <= math.pi
    turns = (a - w) / (2 * math.pi)
    assert turns == pytest.approx(round(turns), abs=1e-9)


def test_wrap_angle_edges_and_arrays() -> None:
    np.testing.assert_array_equal(
        wrap_angle(np.array([math.pi, -math.pi, 3 * math.pi, 0.0])),
        [math.pi, math.pi, math.pi, 0.0],
    )
    assert float(wrap_angle(2 * math.pi)) == pytest.approx(0.0, abs=1e-15)
    assert float(wrap_angle(-math.pi / 2)) == pytest.approx(-math.pi / 2, abs=1e-15)


def test_pose_controller_wraps_heading_error() -> None:
    ctl = PoseController()
    x = np.array([0.0, 0.0, -math.pi + 0.1, 0.0, 0.0, 0.0])
    v = ctl(x, np.array([0.0, 0.0, math.pi - 0.1]))
    assert v[2] == pytest.approx(0.75 * 0.63 * -0.2, abs=1e-12)  # the short way round


def test_state_feedback_reference_gain_gives_unit_dc_gain() -> None:
    """K_r = ((1 - A - B_v K)^-1 B_v)^-1 makes x -> r for the scalar plant of section 4.1."""
    ctl, plant = StateFeedback(), LinearPlant()
    assert ctl.k_r == pytest.approx(0.4)
    x = np.array([0.0])
    for _ in range(200):
        x = plant.step(x, ctl(x, np.array([1.0])), 1.0)
    assert x[0] == pytest.approx(1.0, abs=1e-9)
