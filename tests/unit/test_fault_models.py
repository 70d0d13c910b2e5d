"""Fault schedules as real thrusters fail: ramps, intermittent, stuck, bias, random draws."""

from __future__ import annotations

import math
import re
import tomllib

import numpy as np
import pytest

from ftcap_hil.config.scenario import parse_scenario
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.faults import (
    EventKind,
    FaultEvent,
    FaultSchedule,
    Injection,
    Truth,
    injection_plan,
)
from ftcap_hil.core.messages import FaultKind

F64 = np.float64


def ramp(start: float = 10.0, ramp_s: float = 10.0, **kw: object) -> FaultEvent:
    return FaultEvent(start, math.inf, 1, F64(0.4), F64(0.02), EventKind.RAMP, ramp_s=ramp_s)


def test_step_keeps_exact_values() -> None:
    sched = FaultSchedule(3, (FaultEvent(1.0, 2.0, 2, F64(0.3), F64(0.01)),))
    truth = sched.at(1.5)
    assert truth.delta.tolist() == [1.0, 1.0, 0.3] and truth.f.tolist() == [0.0, 0.0, 0.01]
    assert not truth.stuck.any() and truth.stuck.shape == (3,)
    assert sched.at(2.0).delta.tolist() == [1.0, 1.0, 1.0]


def test_ramp_midway_and_end() -> None:
    sched = FaultSchedule(2, (ramp(),))
    assert sched.at(9.99).delta[1] == 1.0
    assert sched.at(15.0).delta[1] == pytest.approx(0.7)  # half way from 1 to 0.4
    assert sched.at(15.0).f[1] == pytest.approx(0.01)  # half way from 0 to 0.02
    assert sched.at(12.5).delta[1] == pytest.approx(0.85)
    assert sched.at(20.0).delta[1] == 0.4 and sched.at(1e6).f[1] == 0.02
    assert sched.at(15.0).delta[0] == 1.0
    assert sched.change_times() == [10.0, 20.0]


def test_ramp_starts_from_the_earlier_events_value() -> None:
    earlier = FaultEvent(0.0, math.inf, 1, F64(0.8), None)
    sched = FaultSchedule(2, (earlier, ramp()))
    assert sched.at(5.0).delta[1] == 0.8
    assert sched.at(15.0).delta[1] == pytest.approx(0.6)  # half way from 0.8 to 0.4


def test_ramp_cut_by_its_end() -> None:
    ev = FaultEvent(10.0, 14.0, 0, F64(0.0), None, EventKind.RAMP, ramp_s=8.0)
    sched = FaultSchedule(1, (ev,))
    assert sched.at(13.0).delta[0] == pytest.approx(1 - 3 / 8)
    assert sched.at(14.0).delta[0] == 1.0
    assert sched.change_times() == [10.0, 14.0]


def test_intermittent_on_off_pattern() -> None:
    ev = FaultEvent(10.0, 30.0, 0, F64(0.0), None, EventKind.INTERMITTENT, on_s=2.0, off_s=3.0)
    sched = FaultSchedule(1, (ev,))
    on = {t: sched.at(t).delta[0] == 0.0 for t in (9.9, 10, 11.9, 12, 14.9, 15, 16.9, 17, 29.9, 30)}
    assert on == {9.9: False, 10: True, 11.9: True, 12: False, 14.9: False, 15: True,
                  16.9: True, 17: False, 29.9: False, 30: False}  # fmt: skip
    assert sched.change_times() == [10.0, 12.0, 15.0, 17.0, 20.0, 22.0, 25.0, 27.0, 30.0]


def test_intermittent_edges_agree_with_at_under_rounding() -> None:
    ev = FaultEvent(0.1, 100.0, 0, F64(0.5), None, EventKind.INTERMITTENT, on_s=0.1, off_s=0.2)
    sched = FaultSchedule(1, (ev,))
    edges = sched.change_times()
    assert len(edges) == 2 * 333 + 1
    states = [sched.at(t).delta[0] for t in edges[:-1]]
    assert states == [0.5, 1.0] * 333  # each edge already shows the state after it


def test_stuck_sets_the_flag_and_nothing_else() -> None:
    sched = FaultSchedule(
        3,
        (
            FaultEvent(0.0, math.inf, 0, F64(0.5), None),
            FaultEvent(5.0, 8.0, 0, None, None, EventKind.STUCK),
            FaultEvent(6.0, math.inf, 2, None, F64(-0.01), EventKind.BIAS),
        ),
    )
    truth = sched.at(7.0)
    assert truth.stuck.tolist() == [True, False, False]
    assert truth.delta.tolist() == [0.5, 1.0, 1.0] and truth.f.tolist() == [0.0, 0.0, -0.01]
    eff = truth.effective(np.array([0.07, 0.0, 0.0]))
    assert eff.delta.tolist() == [0.0, 1.0, 1.0] and eff.f.tolist() == [0.07, 0.0, -0.01]
    assert not sched.at(8.0).stuck.any()


def test_several_at_once_later_overrides() -> None:
    sched = FaultSchedule(
        2,
        (
            FaultEvent(0.0, 10.0, None, np.array([0.9, 0.8]), np.array([0.0, 0.01])),
            FaultEvent(2.0, 4.0, 1, F64(0.0), None),
        ),
    )
    assert sched.at(3.0).delta.tolist() == [0.9, 0.0] and sched.at(3.0).f.tolist() == [0.0, 0.01]
    assert sched.at(5.0).delta.tolist() == [0.9, 0.8]


def test_truth_without_stuck_is_all_false() -> None:
    assert Truth(np.ones(4), np.zeros(4)).stuck.tolist() == [False] * 4


@pytest.mark.parametrize(
    ("kw", "word"),
    [
        ({"kind": EventKind.INTERMITTENT, "on_s": 1.0, "off_s": 1.0}, "finite end"),
        ({"kind": EventKind.INTERMITTENT, "end": 9.0, "on_s": 1.0}, "off_s"),
        ({"kind": EventKind.RAMP}, "ramp_s"),
        ({"kind": EventKind.STUCK, "delta": F64(0.5)}, "no delta"),
        ({"kind": EventKind.BIAS, "delta": F64(0.5), "bias": F64(0.1)}, "no delta"),
        ({"end": 1.0}, "start < end"),
    ],
)
def test_bad_events(kw: dict[str, object], word: str) -> None:
    args: dict[str, object] = {"start": 1.0, "end": math.inf, "thruster": 0, "delta": None,
                               "bias": None, **kw}  # fmt: skip
    with pytest.raises(ValueError, match=word):
        FaultEvent(**args)  # type: ignore[arg-type]


# --- injection plan ---


def test_plan_for_stuck_and_ramp() -> None:
    sched = FaultSchedule(
        2,
        (
            FaultEvent(1.0, 3.0, 0, None, None, EventKind.STUCK),
            FaultEvent(2.0, math.inf, 1, F64(0.5), None, EventKind.RAMP, ramp_s=4.0),
        ),
    )
    assert injection_plan(sched, 100.0) == [
        Injection(1.0, 0, FaultKind.STUCK),
        Injection(3.0, 0, FaultKind.OK),
        Injection(3.0, 1, FaultKind.WEAK, 0.875),  # the ramp sampled at another change
        Injection(6.0, 1, FaultKind.WEAK, 0.5),  # and at its end
    ]


def test_plan_stuck_over_a_weak_thruster_returns_to_weak() -> None:
    sched = FaultSchedule(
        1,
        (
            FaultEvent(0.0, math.inf, 0, F64(0.6), None),
            FaultEvent(1.0, 2.0, 0, None, None, EventKind.STUCK),
        ),
    )
    plan = injection_plan(sched, 10.0)
    assert [(i.at_s, i.kind, i.value) for i in plan[:2]] == [
        (0.0, FaultKind.WEAK, 0.6),
        (1.0, FaultKind.STUCK, plan[1].value),
    ]
    assert math.isnan(plan[1].value)
    assert plan[2:] == [Injection(2.0, 0, FaultKind.OK), Injection(2.0, 0, FaultKind.WEAK, 0.6)]


# --- scenario files: the [[fault]] profile keys ---

HEAD = """
[scenario]
name = "unit"
dt = 0.5
duration = 60.0
[plant]
kind = "vessel"
[vessel]
preset = "paper-4.2"
[[reference]]
from = 0.0
value = [0.0, 0.0, 0.0]
"""


def parse_faults(text: str) -> FaultSchedule:
    return parse_scenario(tomllib.loads(HEAD + text), "unit.toml").faults


def test_scenario_file_profile_keys() -> None:
    sched = parse_faults(
        """
[[fault]]
from = 10.0
thruster = 1
kind = "ramp"
ramp_s = 10.0
delta = 0.4
[[fault]]
from = 5.0
until = 25.0
thruster = 2
kind = "intermittent"
on_s = 2.0
off_s = 3.0
delta = 0.0
[[fault]]
from = 30.0
until = 40.0
thruster = 3
kind = "stuck"
[[fault]]
from = 1.0
thruster = 4
kind = "bias"
bias = -0.01
"""
    )
    assert [ev.kind for ev in sched.events] == [
        EventKind.RAMP, EventKind.INTERMITTENT, EventKind.STUCK, EventKind.BIAS,
    ]  # fmt: skip
    assert sched.at(15.0).delta[0] == pytest.approx(0.7)
    assert sched.at(6.0).delta[1] == 0.0 and sched.at(8.0).delta[1] == 1.0
    assert sched.at(35.0).stuck.tolist() == [False, False, True, False]
    assert sched.at(2.0).f[3] == -0.01


def test_scenario_without_kind_is_a_step() -> None:
    sched = parse_faults("[[fault]]\nfrom = 1.0\nthruster = 1\ndelta = 0.3\n")
    assert sched.events[0].kind is EventKind.STEP and sched.at(2.0).delta[0] == 0.3


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ('kind = "ramps"\ndelta = 0.5', "kind: 'ramps' is not one of 'step', 'ramp'"),
        ('kind = "ramp"\ndelta = 0.5', "ramp_s: missing"),
        ("ramp_s = 3.0\ndelta = 0.5", "ramp_s: only for kind = 'ramp'"),
        ('kind = "ramp"\non_s = 1.0\nramp_s = 2.0', "on_s: only for kind = 'intermittent'"),
        (
            'kind = "intermittent"\non_s = 1.0\noff_s = 1.0\ndelta = 0.0',
            "intermittent fault: needs a finite end",
        ),
        ('kind = "stuck"\ndelta = 0.0', "stuck fault: takes no delta"),
        ('kind = "ramp"\nramp_s = -1.0\ndelta = 0.5', "ramp fault: ramp_s must be > 0"),
        ("until = 0.5\ndelta = 0.5", "until: expected a time after from = 1, got 0.5"),
    ],
)
def test_scenario_profile_key_errors(entry: str, message: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(f"unit.toml: [[fault]][0] {message}")):
        parse_faults(f"[[fault]]\nfrom = 1.0\nthruster = 1\n{entry}\n")
