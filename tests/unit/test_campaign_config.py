"""Campaign files: strict keys, the plan they give, the fault generator, replay documents."""

from __future__ import annotations

import copy
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from ftcap_hil.config.campaign import (
    CLASSIC_KINDS,
    DrawnKind,
    FaultSpec,
    load_campaign,
    parse_campaign,
    shipped_campaigns,
)
from ftcap_hil.config.scenario import load_scenario, parse_scenario, shipped_scenarios
from ftcap_hil.config.toml import read_toml
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.estimation.config import EstimatorKind
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.campaign_faults import random_faults
from ftcap_hil.runtime.campaign_plan import deep_merge, dumps_toml, plan_campaign

SMALL = """
[campaign]
name = "small"
seeds = [3, 4]
modes = ["ftcap", "ftcap-prefilter"]
duration = 40.0

[[scenario]]
source = "paper-4.2-ex1"
label = "paper"
faults = "random"
[scenario.set.noise]
state_std = [0.0, 0.0, 0.0, 1e-4, 1e-4, 1e-4]

[variant.ftcap-prefilter]
mode = "ftcap"
estimator = { prefilter = 0.3 }

[faults]
kinds = ["dead", "bias"]
onset = [10.0, 20.0]

[healthy]
seed_count = 1
duration = 30.0
"""


def _parse(text: str):  # noqa: ANN202
    return parse_campaign(tomllib.loads(text), "small.toml")


def test_the_shipped_campaigns_parse_and_plan(tmp_path: Path) -> None:
    assert {"smoke", "realistic", "sweeps"} <= set(shipped_campaigns())
    plan, files = plan_campaign(load_campaign("smoke"), tmp_path)
    assert plan.tasks and files
    plan, files = plan_campaign(load_campaign("realistic"), tmp_path)
    assert files
    faulty = [t for t in plan.tasks if not t.healthy]
    assert len(faulty) == 375  # 3 scenarios x 5 kinds x 5 seeds x (none, cap, oracle, 2 ftcap)
    kinds = {t.variant: t.scenario.core.estimator.kind for t in faulty}
    assert kinds["ftcap-windowed"] is EstimatorKind.WINDOWED  # estimator = { kind = "windowed" }
    assert kinds["ftcap"] is EstimatorKind.KALMAN


def test_the_sweeps_campaign_states_its_conditions_and_seeds() -> None:
    """Parsed (planning its runs takes minutes: the campaign does it)."""
    spec = load_campaign("sweeps")
    labels = [s.label for s in spec.scenarios]
    assert labels == ["cs2-current-0.25", "cs2-current-0.50", "cs2-current-1.25"] + [
        f"supply-bf{b}" for b in range(2, 7)
    ]
    assert spec.tuning_seeds == (1001, 1002, 1003) and spec.seeds == (0, 1, 2, 3, 4)
    assert spec.faults.causes and len(spec.faults.kinds) == len(DrawnKind)
    waves = [s.overrides["environment"]["waves"]["hs_m"] for s in spec.scenarios[3:]]
    assert waves == sorted(waves) and waves[3] == pytest.approx(2.1407, abs=1e-4)  # Bf 5
    motion = next(v for v in spec.variants if v.name == "ftcap-motion")
    assert motion.tables == {"diagnosis": {"enabled": False}}


def test_a_variants_bad_estimator_kind_is_refused_when_planning(tmp_path: Path) -> None:
    text = SMALL.replace("estimator = { prefilter = 0.3 }", 'estimator = { kind = "windowd" }')
    with pytest.raises(ConfigError, match=r"\[estimator\] kind: 'windowd' is not one of"):
        plan_campaign(_parse(text), tmp_path)


def _typo(table: str, key: str):  # noqa: ANN202
    """A mutation of the SMALL document: ``key`` added to ``table`` (a dotted path)."""

    def change(data: dict) -> None:
        target = data
        for part in table.split(".") if table else []:
            target = target[int(part)] if part.isdigit() else target.setdefault(part, {})
        target[key] = 1

    return change


@pytest.mark.parametrize(
    ("table", "key", "where", "hint"),
    [
        ("campaign", "seed", "small.toml: [campaign]", "'seeds'"),
        ("scenario.0", "sorce", "small.toml: [[scenario]][0]", "'source'"),
        ("faults", "onsett", "small.toml: [faults]", "'onset'"),
        ("metrics", "convergence_tol_x", "small.toml: [metrics]", "'convergence_tol'"),
        (
            "variant.ftcap-prefilter",
            "estimater",
            "small.toml: [variant.ftcap-prefilter]",
            "'estimator'",
        ),
        ("healthy", "duraton", "small.toml: [healthy]", "'duration'"),
        ("", "extra", "small.toml:", "valid keys: campaign, faults"),
    ],
)
def test_an_unknown_key_names_the_file_the_table_and_the_nearest_key(
    table: str, key: str, where: str, hint: str
) -> None:
    data = tomllib.loads(SMALL)
    _typo(table, key)(data)
    with pytest.raises(ConfigError) as err:
        parse_campaign(data, "small.toml")
    msg = str(err.value)
    assert msg.startswith(
        f"{where} unknown key {key!r} (did you mean {hint}?)" if hint[0] == "'" else where
    )
    assert f"unknown key {key!r}" in msg and hint in msg, msg


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ({"campaign": {"modes": ["ftcap", "nope"]}}, "'nope' is no mode"),
        ({"campaign": {"seed_count": 2}}, "one of them"),
        ({"faults": {"kinds": ["rampe"]}}, r"\[faults\] kinds: expected a list from"),
        ({"faults": {"onset": [5.0, 1.0]}}, r"\[faults\] onset: expected \[low, high\]"),
        ({"faults": {"partial_delta": [0.5, 1.0]}}, "below 1"),
        ({"metrics": {"harm_ratio": 0.9}}, "harm_ratio"),
        ({"variant": {"ftcap-prefilter": {"mode": "none"}}}, "mode"),
        ({"variant": {"cap": {"mode": "ftcap"}}}, "mode's name"),
        ({"campaign": {"tuning_seeds": [4, 1001]}}, r"tuning_seeds: seeds \[4\] are also"),
        ({"campaign": {"tuning_seeds": [0, 1001]}}, r"seeds \[0\] are also evaluated"),
    ],
)
def test_bad_values_are_config_errors(change: dict, needle: str) -> None:
    with pytest.raises(ConfigError, match=needle):
        parse_campaign(deep_merge(tomllib.loads(SMALL), change), "small.toml")


def test_tuning_seeds_disjoint_from_the_evaluated_ones_are_kept() -> None:
    doc = deep_merge(tomllib.loads(SMALL), {"campaign": {"tuning_seeds": [1001, 1002]}})
    assert parse_campaign(doc, "small.toml").tuning_seeds == (1001, 1002)
    assert parse_campaign(tomllib.loads(SMALL), "small.toml").tuning_seeds == ()


def test_a_bad_scenario_override_fails_when_planning(tmp_path: Path) -> None:
    data = deep_merge(
        tomllib.loads(SMALL), {"variant": {"ftcap-prefilter": {"estimator": {"prefiltr": 0.3}}}}
    )
    with pytest.raises(ConfigError, match="prefiltr"):
        plan_campaign(parse_campaign(data, "small.toml"), tmp_path)


def test_the_plan_has_one_reference_per_case_and_shares_it(tmp_path: Path) -> None:
    plan, files = plan_campaign(_parse(SMALL), tmp_path)
    cases = {t.case for t in plan.tasks}
    faulty = {c for c in cases if "healthy" not in c}
    assert faulty == {f"paper/s{s}/{k}" for s in (3, 4) for k in ("dead", "bias")}
    assert cases - faulty == {"paper/healthy/s0"}
    for case in cases:
        variants = sorted(t.variant for t in plan.tasks if t.case == case)
        expect = ["cap", "ftcap", "ftcap-prefilter", "none", "oracle"]
        assert variants == (["ftcap", "ftcap-prefilter", "none"] if "healthy" in case else expect)
    keys = [t.key for t in plan.tasks]
    assert len(set(keys)) == len(keys) and len({t.digest for t in plan.tasks}) == len(keys)
    pre = next(t for t in plan.tasks if t.variant == "ftcap-prefilter")
    assert pre.mode is Mode.FTCAP and pre.scenario.core.estimator.prefilter == 0.3
    plain = next(t for t in plan.tasks if t.variant == "ftcap" and t.case == pre.case)
    assert plain.scenario.core.estimator.prefilter == 0.0
    assert all(t.scenario.seed == t.seed for t in plan.tasks)
    assert list(pre.scenario.noise_std[3:]) == [1e-4] * 3
    assert {t.scenario.duration_s for t in plan.tasks} == {40.0, 30.0}
    assert all(not t.scenario.faults.events for t in plan.tasks if t.healthy)
    # the replay files: one per case, and one more per case for the variant
    assert len(files) == len(cases) * 2


def test_replay_files_are_the_runs_scenarios(tmp_path: Path) -> None:
    plan, files = plan_campaign(_parse(SMALL), tmp_path)
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    for task in plan.tasks:
        path = Path(task.replay.split()[2])
        assert f"--mode {task.mode.value}" in task.replay
        sc = load_scenario(tmp_path / path.name).with_mode(task.mode)
        assert _same_faults(sc, task.scenario)
        assert sc.core == task.scenario.core and sc.seed == task.seed
        assert sc.duration_s == task.scenario.duration_s


def _same_faults(a, b) -> bool:  # noqa: ANN001
    times = sorted(set(a.faults.change_times()) | set(b.faults.change_times()))
    return all(
        np.array_equal(a.faults.at(t).delta, b.faults.at(t).delta)
        and np.array_equal(a.faults.at(t).f, b.faults.at(t).f)
        for t in times
    )


@pytest.mark.parametrize("name", shipped_scenarios())
def test_dumps_toml_round_trips_every_shipped_scenario(name: str) -> None:
    data = read_toml(name, "ftcap_hil.data.scenarios").data
    doc = copy.deepcopy(data)
    doc["fault"] = [*data.get("fault", []), {"thruster": 1, "from": 0.1 + 0.2, "until": math.inf}]
    doc["scenario"]["note"] = 'quote " and unicode \u03b4'
    back = tomllib.loads(dumps_toml(doc))
    assert back == doc


def test_dumps_toml_nested_tables_and_arrays_of_tables() -> None:
    doc = {"a": {"b": {"c": 1}, "x": [{"k": 1.5e-300}, {"k": -2}]}, "top": True, "l": [[1, 2]]}
    assert tomllib.loads(dumps_toml(doc)) == doc


def test_the_generator_is_reproducible_and_follows_its_ranges() -> None:
    u_range = np.full(4, 0.1)
    spec = FaultSpec(count=2, onset=(10.0, 20.0), bias=(0.1, 0.3), stuck=(0.2, 0.6))
    draws = [random_faults(np.random.default_rng(7), u_range, 100.0, spec) for _ in range(2)]
    assert draws[0] == draws[1]
    other = random_faults(np.random.default_rng(8), u_range, 100.0, spec)
    assert other != draws[0]
    for seed in range(40):
        for kind in CLASSIC_KINDS:
            gen = random_faults(np.random.default_rng(seed), u_range, 100.0, spec, kind)
            assert len({g.thruster for g in gen}) == 2
            for g in gen:
                _check(g.kind, g.tables, spec)


def _check(kind: DrawnKind, tables: tuple, spec: FaultSpec) -> None:
    first = tables[0]
    assert 10.0 <= first["from"] <= 20.0
    if kind is DrawnKind.INTERMITTENT:
        assert len(tables) >= 2 and all(t["delta"] == 0.0 for t in tables)
        for a, b in zip(tables[:-1], tables[1:], strict=True):
            off = b["from"] - a["until"]
            assert spec.intermittent_off[0] <= off <= spec.intermittent_off[1]
        assert tables[-1]["until"] <= 100.0
        return
    assert len(tables) == 1 and "until" not in first  # permanent without a duration range
    if kind is DrawnKind.PARTIAL:
        assert 0.3 <= first["delta"] <= 0.7 and first["bias"] == 0.0
    elif kind is DrawnKind.BIAS:
        assert first["delta"] == 1.0 and 0.01 <= abs(first["bias"]) <= 0.03
    elif kind is DrawnKind.STUCK:
        assert first["delta"] == 0.0 and 0.02 <= abs(first["bias"]) <= 0.06
    else:
        assert (first["delta"], first["bias"]) == (0.0, 0.0)


def test_the_new_kinds_give_ramps_frozen_outputs_transients_doubles_and_lost_telemetry() -> None:
    spec = FaultSpec(count=1, onset=(10.0, 20.0), causes=True)
    u_range = np.full(4, 0.1)
    seen_causes: set[str] = set()
    for seed in range(60):
        draw = {k: random_faults(np.random.default_rng(seed), u_range, 300.0, spec, k)
                for k in DrawnKind}  # fmt: skip
        ((ramp,),) = [g.tables for g in draw[DrawnKind.RAMP]]
        assert ramp["kind"] == "ramp" and 0.0 <= ramp["delta"] <= 0.5
        assert 30.0 <= ramp["ramp_s"] <= 120.0 and ramp["cause"] in (
            "weak-motor",
            "fouled",
            "hull-loss",
        )
        ((frozen,),) = [g.tables for g in draw[DrawnKind.FROZEN]]
        assert frozen["kind"] == "stuck" and "cause" not in frozen
        ((transient,),) = [g.tables for g in draw[DrawnKind.TRANSIENT]]
        assert 20.0 <= transient["until"] - transient["from"] <= 60.0 and transient["delta"] == 0.0
        a, b = draw[DrawnKind.DOUBLE]
        assert a.thruster != b.thruster and a.kind is b.kind is DrawnKind.DOUBLE
        assert a.tables[0]["from"] == b.tables[0]["from"] and a.tables[0]["delta"] == 0.0
        ((lost,),) = [g.tables for g in draw[DrawnKind.TELEMETRY_LOST]]
        assert (lost["delta"], lost["bias"], lost["cause"]) == (1.0, 0.0, "telemetry-lost")
        seen_causes |= {t["cause"] for g in draw[DrawnKind.DEAD] for t in g.tables}
    assert seen_causes == {"drive-dead", "power-lost", "jammed"}
    plain = random_faults(np.random.default_rng(1), u_range, 300.0, FaultSpec(), DrawnKind.DEAD)
    assert "cause" not in plain[0].tables[0]  # causes off: the default of its delta
    # delta 0 with a force left: with causes, a silent drive holding it, labelled so; the
    # draws are those of causes off (its one cause costs no draw)
    (held,) = random_faults(np.random.default_rng(3), u_range, 300.0, spec, DrawnKind.STUCK)
    (stuck,) = random_faults(
        np.random.default_rng(3), u_range, 300.0, FaultSpec(count=1, onset=(10.0, 20.0)),
        DrawnKind.STUCK,
    )  # fmt: skip
    assert (held.tables[0]["cause"], held.label) == ("held", "held")
    assert "cause" not in stuck.tables[0] and stuck.label == "stuck"
    assert {k: v for k, v in held.tables[0].items() if k != "cause"} == stuck.tables[0]
    with pytest.raises(ValueError, match="each_kind"):
        random_faults(
            np.random.default_rng(1), u_range, 300.0, FaultSpec(kinds=(DrawnKind.DOUBLE,))
        )


def test_every_new_kind_plans_into_scenarios_that_load(tmp_path: Path) -> None:
    doc = deep_merge(tomllib.loads(SMALL), {"faults": {"kinds": [k.value for k in DrawnKind]}})
    plan, _ = plan_campaign(parse_campaign(doc, "small.toml"), tmp_path)
    kinds = {t.kind for t in plan.tasks}
    assert {"ramp", "frozen", "transient", "double", "telemetry-lost"} <= kinds


def test_faults_with_a_duration_range_end_within_it() -> None:
    """(Ported from the former core/random_faults.py tests, as the ones below.)"""
    spec = FaultSpec(count=3, onset=(10.0, 20.0), duration=(5.0, 15.0))
    rng = np.random.default_rng(0)
    for kind in (DrawnKind.DEAD, DrawnKind.PARTIAL, DrawnKind.BIAS, DrawnKind.STUCK):
        for _ in range(50):
            for g in random_faults(rng, np.full(4, 0.1), 100.0, spec, kind):
                (t,) = g.tables
                assert 5.0 <= t["until"] - t["from"] <= 15.0


def test_intermittent_faults_are_on_and_off_for_their_ranges_and_end_in_the_run() -> None:
    spec = FaultSpec(count=1, onset=(10.0, 20.0), duration=(30.0, 60.0))
    rng = np.random.default_rng(3)
    for _ in range(50):
        (g,) = random_faults(rng, np.full(4, 0.1), 50.0, spec, DrawnKind.INTERMITTENT)
        ons = [t["until"] - t["from"] for t in g.tables]
        assert all(on <= spec.intermittent_on[1] for on in ons)
        assert all(on >= spec.intermittent_on[0] for on in ons[:-1])  # the last one may be cut
        assert g.tables[-1]["until"] <= 50.0


def test_drawn_kinds_come_from_the_spec_and_every_one_is_drawn() -> None:
    rng = np.random.default_rng(5)
    only = FaultSpec(kinds=(DrawnKind.STUCK, DrawnKind.BIAS), count=2)
    seen = {g.kind for _ in range(100) for g in random_faults(rng, np.full(4, 0.1), 60.0, only)}
    assert seen == {DrawnKind.STUCK, DrawnKind.BIAS}
    every = FaultSpec(count=1)
    seen = {g.kind for _ in range(200) for g in random_faults(rng, np.full(4, 0.1), 60.0, every)}
    assert seen == set(CLASSIC_KINDS)  # the default kinds: the first generator's


def test_faults_fall_on_the_allowed_thrusters_once_each_in_thruster_order() -> None:
    spec = FaultSpec(count=2, thrusters=(1, 3))
    rng = np.random.default_rng(2)
    for _ in range(30):
        gen = random_faults(rng, np.full(5, 0.1), 60.0, spec, DrawnKind.DEAD)
        assert [g.thruster for g in gen] == [1, 3]
        assert [t["thruster"] for g in gen for t in g.tables] == [2, 4]  # 1-based in the file
    with pytest.raises(ValueError, match="faults.count = 3 but only 2 thrusters allowed"):
        random_faults(rng, np.full(5, 0.1), 60.0, FaultSpec(count=3, thrusters=(1, 3)))
    with pytest.raises(ValueError, match="the vessel has 5 thrusters"):
        random_faults(rng, np.full(5, 0.1), 60.0, FaultSpec(thrusters=(7,)))


def test_changing_one_severity_range_changes_no_other_draw() -> None:
    u_range = np.full(4, 0.1)
    base = FaultSpec(count=2, duration=(5.0, 15.0))
    other = FaultSpec(count=2, duration=(5.0, 15.0), stuck=(0.4, 0.5), partial_delta=(0.1, 0.2))
    for seed in range(20):
        a = random_faults(np.random.default_rng(seed), u_range, 60.0, base)
        b = random_faults(np.random.default_rng(seed), u_range, 60.0, other)
        assert [(g.thruster, g.kind) for g in a] == [(g.thruster, g.kind) for g in b]
        assert [g.tables[0]["from"] for g in a] == [g.tables[0]["from"] for g in b]


def test_generated_tables_are_valid_scenario_faults() -> None:
    data = read_toml("paper-4.2-ex1", "ftcap_hil.data.scenarios").data
    spec = FaultSpec(count=4, duration=(5.0, 10.0))
    gen = random_faults(np.random.default_rng(1), np.full(4, 0.1), 700.0, spec)
    data["fault"] = [t for g in gen for t in g.tables]
    sc = parse_scenario(data, "generated")
    assert len(sc.faults.events) == len(data["fault"])
    for ev, t in zip(sc.faults.events, data["fault"], strict=True):
        assert ev.thruster == t["thruster"] - 1 and ev.end == t["until"] < math.inf


def test_too_many_faults_for_the_vessel_is_a_config_error(tmp_path: Path) -> None:
    data = deep_merge(tomllib.loads(SMALL), {"faults": {"count": 5}})
    with pytest.raises(ConfigError, match="count = 5"):
        plan_campaign(parse_campaign(data, "small.toml"), tmp_path)


def test_scenario_faults_keep_the_files_schedule_and_none_removes_it(tmp_path: Path) -> None:
    text = SMALL.replace('faults = "random"', 'faults = "scenario"\nduration = 300.0')
    text += '\n[[scenario]]\nsource = "paper-4.2-ex1"\nlabel = "calm"\nfaults = "none"\n'
    plan, _ = plan_campaign(_parse(text), tmp_path)
    paper = next(t for t in plan.tasks if t.case == "paper/s3" and t.variant == "ftcap")
    # eqs. (27)-(28): thruster 1 at 0.9 with a bias, then 0.8; thruster 3 stuck at 0.01
    assert dict(paper.fault_kinds) == {0: "mixed", 2: "stuck"} and paper.kind == "multi"
    assert _same_faults(paper.scenario, load_scenario("paper-4.2-ex1"))
    calm = [t for t in plan.tasks if t.label == "calm"]
    assert calm and all(t.healthy and not t.scenario.faults.events for t in calm)
    assert {t.variant for t in calm} == {"none", "ftcap", "ftcap-prefilter"}
