"""Omega(u_prev) of eq. (2): amplitude box intersected with the rate box."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ftcap_hil.core.effectiveness.geometry import command_bounds

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False)


@st.composite
def bound_cases(draw: st.DrawFn) -> tuple[float, float, float, float]:
    u_min = -draw(st.floats(min_value=0.0, max_value=1e3))
    u_max = draw(st.floats(min_value=0.0, max_value=1e3))
    step = draw(st.one_of(st.floats(min_value=1e-9, max_value=1e3), st.just(math.inf)))
    inside = draw(st.booleans())
    if inside:
        u_prev = draw(st.floats(min_value=u_min, max_value=u_max))
    else:
        u_prev = draw(finite)
    return u_min, u_max, step, u_prev


@settings(max_examples=300, deadline=None)
@given(cases=st.lists(bound_cases(), min_size=1, max_size=6))
def test_bounds_invariants(cases: list[tuple[float, float, float, float]]) -> None:
    u_min, u_max, step, u_prev = (np.array(c) for c in zip(*cases, strict=True))
    lo, hi = command_bounds(u_min, u_max, step, u_prev)
    assert lo.shape == hi.shape == u_prev.shape
    assert np.all(lo <= hi)
    assert np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))
    tol = 1e-12 * (1.0 + np.abs(u_prev) + np.where(np.isfinite(step), step, 0.0))
    # Never more than one step from the previous command.
    assert np.all(np.abs(lo - u_prev) <= step + tol)
    assert np.all(np.abs(hi - u_prev) <= step + tol)
    inside = (u_min <= u_prev) & (u_prev <= u_max)
    # From inside the amplitude range: the box stays inside it and contains u_prev.
    assert np.all(lo[inside] >= u_min[inside])
    assert np.all(hi[inside] <= u_max[inside])
    assert np.all(lo[inside] <= u_prev[inside]) and np.all(u_prev[inside] <= hi[inside])
    # From outside: the box never points further away from the range.
    above, below = u_prev > u_max, u_prev < u_min
    assert np.all(hi[above] <= u_prev[above])
    assert np.all(lo[below] >= u_prev[below])


def test_bounds_literal_cases() -> None:
    u_min = np.array([-0.1, -0.1, -0.1, -0.1, -0.1])
    u_max = np.array([0.1, 0.1, 0.1, 0.1, 0.1])
    step = np.array([0.09, 0.09, 0.09, 0.09, 0.01])
    u_prev = np.array([0.0, 0.05, 0.5, -0.15, 0.3])
    lo, hi = command_bounds(u_min, u_max, step, u_prev)
    np.testing.assert_allclose(lo, [-0.09, -0.04, 0.41, -0.1, 0.29], rtol=0, atol=1e-15)
    np.testing.assert_allclose(hi, [0.09, 0.1, 0.41, -0.06, 0.29], rtol=0, atol=1e-15)


def test_bounds_do_not_mutate_inputs() -> None:
    u_prev = np.array([0.5, -0.5])
    copy = u_prev.copy()
    command_bounds(np.array([-0.1, -0.1]), np.array([0.1, 0.1]), np.array([0.09, 0.09]), u_prev)
    np.testing.assert_array_equal(u_prev, copy)
