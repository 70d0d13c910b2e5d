"""A frozen output (``[[fault]] kind = "stuck"``): the campaign plan labels it ``frozen``, not
``healthy``, and the offline loop freezes the thruster and records it as not nominal."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.config.campaign import MetricParams, parse_campaign
from ftcap_hil.config.scenario import parse_scenario
from ftcap_hil.config.toml import read_toml
from ftcap_hil.core.status import Mode
from ftcap_hil.report.campaign_metrics import episodes, run_metrics
from ftcap_hil.runtime.campaign_plan import FROZEN, dumps_toml, plan_campaign, schedule_kinds
from ftcap_hil.runtime.offline import run_mode

CAMPAIGN = """
[campaign]
name = "frozen"
seeds = [1]
modes = ["ftcap"]
duration = 30.0

[[scenario]]
source = "frozen.toml"
faults = "scenario"
"""


def _paper(faults: list[dict[str, Any]], duration_s: float = 30.0) -> dict[str, Any]:
    """The paper's vessel (section 4.2) with ``faults`` for its [[fault]] tables."""
    doc = read_toml("paper-4.2-ex1", "ftcap_hil.data.scenarios").data
    doc["fault"] = faults
    doc["scenario"]["duration"] = duration_s
    return doc


FROZEN_2 = {"from": 15.0, "thruster": 2, "kind": "stuck"}


def test_a_scenario_whose_only_fault_is_a_frozen_output_is_planned_as_frozen(
    tmp_path: Path,
) -> None:
    (tmp_path / "frozen.toml").write_text(dumps_toml(_paper([FROZEN_2])))
    spec = parse_campaign(tomllib.loads(CAMPAIGN), "frozen-campaign.toml", tmp_path)
    plan, _ = plan_campaign(spec, tmp_path / "out")
    assert {t.variant for t in plan.tasks} == {"none", "cap", "oracle", "ftcap"}
    for task in plan.tasks:
        assert not task.healthy
        assert task.kind == FROZEN == "frozen"  # was "healthy": the per-kind healthy rows
        assert task.fault_kinds == ((1, "frozen"),)


def test_schedule_kinds_tells_a_frozen_output_from_the_other_faults() -> None:
    sc = parse_scenario(
        _paper(
            [
                FROZEN_2,
                {"from": 5.0, "until": 20.0, "thruster": 1, "kind": "stuck"},
                {"from": 25.0, "thruster": 1, "delta": 0.0},  # frozen, then dead: both
                {"from": 12.0, "thruster": 3, "delta": 0.5},
            ]
        ),
        "kinds.toml",
    )
    assert schedule_kinds(sc) == {0: "mixed", 1: "frozen", 2: "partial"}


def test_schedule_kinds_keeps_the_kind_a_file_names_for_ramps_and_intermittent_faults() -> None:
    """A ramp in a scenario file was labelled ``partial`` (its delta below 1), an
    intermittent fault ``dead``: the per-kind tables then mixed them with steps."""
    ramp = {"from": 5.0, "thruster": 1, "kind": "ramp", "delta": 0.3, "ramp_s": 10.0}
    spells = {"from": 5.0, "until": 25.0, "thruster": 2, "kind": "intermittent", "delta": 0.0}
    spells |= {"on_s": 2.0, "off_s": 3.0}
    step = {"from": 12.0, "thruster": 3, "delta": 0.5}
    late_ramp = {"from": 20.0, "thruster": 3, "kind": "ramp", "delta": 0.0, "ramp_s": 5.0}
    sc = parse_scenario(_paper([ramp, spells, step, late_ramp]), "kinds.toml")
    assert schedule_kinds(sc) == {0: "ramp", 1: "intermittent", 2: "ramp"}
    sc = parse_scenario(_paper([ramp, spells, step], duration_s=30.0), "kinds.toml")
    assert schedule_kinds(sc)[2] == "partial"  # a step stays what its values say


def test_the_offline_loop_freezes_the_output_and_records_it_as_not_nominal() -> None:
    sc = parse_scenario(_paper([FROZEN_2]), "frozen.toml")
    rec = run_mode(sc, Mode.CAP)
    c, t = rec.columns, rec.t
    before, after = t < 15.0, t > 15.0 + sc.dt_s
    # the thruster's output is what it was at the onset, whatever it is commanded since
    held = c["tau_2"][np.flatnonzero(before)[-1]]
    assert abs(held) > 0.01
    assert np.ptp(c["u_2"][after]) > 0.01  # its commands move ...
    np.testing.assert_allclose(c["tau_2"][after], held)  # ... its output does not
    assert np.all(c["delta_2"][after] == 0.0) and np.all(c["f_2"][after] == held)
    assert np.all(c["delta_2"][before] == 1.0) and np.all(c["f_2"][before] == 0.0)
    eps = episodes(rec, schedule_kinds(sc))
    assert [(e.thruster, e.kind) for e in eps] == [(1, "frozen")]
    assert t[eps[0].start] >= 15.0 > t[eps[0].start - 1]
    rows = run_metrics(rec, None, MetricParams(), schedule_kinds(sc))["faults"]
    assert [(r["thruster"], r["kind"]) for r in rows] == [(2, "frozen")]
