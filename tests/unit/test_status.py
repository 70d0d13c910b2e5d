"""AllocatorStatus.checked: the one place a status is validated, and what it normalises."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.status import AllocatorStatus, Mode

FULL: dict[str, object] = dict(
    mode=Mode.FTCAP,
    cycle=np.int64(7),
    overruns=1,
    degraded=np.bool_(True),
    setpoint_stale=False,
    telemetry_stale=True,
    estimation_frozen=True,
    delta_hat=np.array([1.0, 0.5]),
    delta_std=[0.01, math.nan],
    observable=np.array([True, False]),
    f_hat=(0.0, 2.5),
    bf_hat=np.array([2.5, 0.0, -1.0]),
    u=[10.0, -4.0],
    tau_demand=(1.0, 2.0, 3.0),
    unallocated=np.zeros(3),
    saturated=[False, True],
    faulty=(False, True),
    esc_failed=np.array([True, False]),
    probing=(False, False),
    setpoint_age_s=0.02,
    telemetry_age_s=math.inf,
    malformed=3,
    esc_rpm=[1500.0, math.nan],
    esc_current_a=(1.25, math.nan),
    esc_age_s=np.array([0.01, math.inf]),
    hypothesis=["healthy", "drive-dead"],
)


def test_checked_keeps_every_field_as_plain_tuples() -> None:
    st = AllocatorStatus.checked(**FULL)
    assert {f.name for f in dataclasses.fields(AllocatorStatus)} == set(FULL)
    assert st.delta_hat == (1.0, 0.5) and type(st.delta_hat[0]) is float
    assert st.observable == (True, False) and type(st.observable[0]) is bool
    assert st.bf_hat == (2.5, 0.0, -1.0) and st.unallocated == (0.0, 0.0, 0.0)
    assert st.esc_failed == (True, False) and st.esc_age_s == (0.01, math.inf)
    assert st.cycle == 7 and type(st.cycle) is int and st.degraded is True
    assert st.mode is Mode.FTCAP and st.malformed == 3 and st.telemetry_age_s == math.inf
    assert math.isnan(st.delta_std[1]) and math.isnan(st.esc_rpm[1])
    assert st.hypothesis == ("healthy", "drive-dead")


def test_a_hypothesis_must_be_a_known_one_per_thruster() -> None:
    with pytest.raises(MalformedMessage, match="hypothesis: unknown 'dead'"):
        AllocatorStatus.checked(**{**FULL, "hypothesis": ["healthy", "dead"]})
    with pytest.raises(MalformedMessage, match="hypothesis: expected 0 or 2"):
        AllocatorStatus.checked(**{**FULL, "hypothesis": ["healthy"]})


def test_checked_of_nothing_is_the_default_status() -> None:
    assert AllocatorStatus.checked() == AllocatorStatus()


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"u": [1.0, 2.0, 3.0]}, "u: expected 0 or 2 entries, got 3"),
        ({"probing": (True,)}, "probing: expected 0 or 2 entries"),
        ({"esc_age_s": (0.1,)}, "esc_age_s: expected 0 or 2"),
        ({"tau_demand": (1.0, 2.0)}, "tau_demand: expected 0 or 3 entries, got 2"),
        ({"f_hat": (0.0, math.inf)}, "f_hat: non-finite"),
        ({"unallocated": (0.0, math.nan, 0.0)}, "unallocated: non-finite"),
        ({"delta_hat": [[1.0, 1.0]]}, "delta_hat: expected a vector"),
        ({"delta_hat": ["a", "b"]}, "delta_hat: not a numeric vector"),
        ({"mode": "ftcap"}, "mode: 'ftcap' is not a Mode"),
    ],
)
def test_checked_refuses_a_status_that_breaks_a_rule(changes: dict[str, Any], match: str) -> None:
    with pytest.raises(MalformedMessage, match=match):
        AllocatorStatus.checked(**{**FULL, **changes})


def test_checked_refuses_a_name_that_is_not_a_field() -> None:
    with pytest.raises(TypeError, match="delta"):
        AllocatorStatus.checked(delta=(1.0,))


def test_flagged_joins_the_estimators_flags_and_the_esc_watchdogs() -> None:
    st = AllocatorStatus.checked(**FULL)
    assert st.flagged == (True, True)
    only_faulty = AllocatorStatus.checked(delta_hat=(1.0, 1.0), faulty=(False, True))
    assert only_faulty.flagged == (False, True)
    only_esc = AllocatorStatus.checked(delta_hat=(1.0, 1.0), esc_failed=(True, False))
    assert only_esc.flagged == (True, False)
    assert AllocatorStatus.checked(delta_hat=(1.0, 1.0)).flagged == ()


def test_command_is_the_last_u_as_a_message() -> None:
    cmd = AllocatorStatus.checked(**FULL).command
    np.testing.assert_array_equal(cmd.u, [10.0, -4.0])
    assert cmd.u.dtype == np.float64


def test_statuses_with_the_same_unknowns_compare_equal() -> None:
    a = AllocatorStatus.checked(delta_hat=(1.0,), esc_rpm=np.array([math.nan]))
    b = AllocatorStatus.checked(delta_hat=(1.0,), esc_rpm=[float("nan")])
    assert a == b
