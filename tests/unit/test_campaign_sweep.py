"""The sweep map (report/campaign_sweep.py) and report.md on constructed rows."""

from __future__ import annotations

from pathlib import Path

import pytest

from ftcap_hil.report.campaign_report import cell, report_markdown
from ftcap_hil.report.campaign_sweep import sweep_rows


def _fault(scenario: str, delay: float | None, kind: str = "dead", detectable: bool = True) -> dict:
    return {"variant": "ftcap", "mode": "ftcap", "scenario": scenario, "kind": kind,
            "detectable": detectable, "isolation_delay_s": delay}  # fmt: skip


def _run(scenario: str, hours: float, episodes: int, mode: str = "ftcap") -> dict:
    return {"variant": mode, "mode": mode, "scenario": scenario, "status": "ok",
            "healthy_hours": hours, "false_alarm_episodes": episodes,
            "removal_switches": 0}  # fmt: skip


def test_each_condition_of_a_sweep_gets_its_isolation_shares_and_false_alarm_rate() -> None:
    """Beaufort 3: dead thrusters isolated in 1, 4, 20 s and never; Beaufort 6: never,
    never; a fault the threshold cannot see is left out; 10 healthy hours with 2 episodes
    in Beaufort 3; the reference modes get no healthy row."""
    rows = [_run("bf3", 10.0, 2), _run("bf6", 4.0, 0), _run("bf3", 10.0, 0, mode="cap")]
    faults = [_fault("bf3", d) for d in (1.0, 4.0, 20.0, None)]
    faults += [_fault("bf6", None), _fault("bf6", None), _fault("bf6", 3.0, detectable=False)]
    out = {(r["scenario"], r["kind"]): r for r in sweep_rows(rows, faults)}
    assert list(out) == [("bf3", "dead"), ("bf6", "dead"), ("bf3", "healthy"), ("bf6", "healthy")]
    bf3 = out[("bf3", "dead")]
    assert (bf3["isolated_5s"], bf3["isolated_30s"], bf3["never"]) == (0.5, 0.75, 0.25)
    assert bf3["isolated_5s_n"] == 4 and bf3["isolated_5s_lo"] == pytest.approx(0.15, abs=0.01)
    bf6 = out[("bf6", "dead")]
    assert bf6["faults"] == 2 and bf6["never"] == 1.0 and bf6["isolated_30s"] == 0.0
    healthy = out[("bf3", "healthy")]
    assert healthy["healthy_hours"] == 10.0 and healthy["false_alarm_episodes_per_h"] == 0.2
    assert healthy["false_alarm_episodes_per_h_hi"] == pytest.approx(0.7225, abs=1e-3)
    assert out[("bf6", "healthy")]["removal_switches_per_h_hi"] == pytest.approx(
        3.6889 / 4, abs=1e-3
    )
    assert cell(bf3, "never") == "25 % [4.56 %, 69.9 %] (4)"


def test_the_report_links_the_tables_and_embeds_every_plot() -> None:
    text = report_markdown(
        {"name": "sweep", "description": "d"},
        [Path("x/by_kind.png"), Path("x/sweep_map.png"), Path("x/isolation_by_kind.png")],
    )
    assert text.startswith("# Campaign sweep: report")
    assert "[summary.md](summary.md)" in text and "[faults.csv](faults.csv)" in text
    images = [ln for ln in text.splitlines() if ln.startswith("![")]
    assert images == ["![sweep_map](sweep_map.png)", "![isolation_by_kind](isolation_by_kind.png)",
                      "![by_kind](by_kind.png)"]  # fmt: skip


def test_the_summary_says_which_seeds_were_evaluated_and_which_tuned() -> None:
    from ftcap_hil.report.campaign_report import _seeds_text

    rows = [{"seed": s} for s in (3, 1, 2, 7, 2)]
    assert _seeds_text(rows, [1001, 1002, 1003]) == (
        " Evaluated on seeds 1-3, 7; thresholds tuned on seeds 1001-1003 (disjoint)."
    )
    assert _seeds_text(rows, []) == " Evaluated on seeds 1-3, 7."


def test_the_headline_pools_a_conditions_faults_harm_and_healthy_hours() -> None:
    from ftcap_hil.report.campaign_report import headline_block
    from ftcap_hil.report.campaign_sweep import headline_rows

    rows = [_run("bf3", 10.0, 2)] + [
        {**_run("bf3", 0.0, 0), "harm": h, "dev_ratio_oracle": d}
        for h, d in ((True, 1.3), (False, 1.0), (None, 0.9), (False, 1.1))
    ]
    faults = [_fault("bf3", d, kind=k) for d, k in ((2.0, "dead"), (40.0, "ramp"), (None, "ramp"))]
    (row,) = headline_rows(rows, faults)
    assert (row["mode"], row["scenario"], row["healthy_hours"], row["faults"]) == (
        "ftcap",
        "bf3",
        10.0,
        3,
    )
    assert row["false_alarm_episodes_per_h"] == 0.2 and row["false_alarm_episodes_per_h_n"] == 2
    assert (row["isolated_5s"], row["isolated_30s"], row["never"]) == (1 / 3, 1 / 3, 1 / 3)
    assert row["harm_share"] == pytest.approx(1 / 3) and row["harm_share_n"] == 3  # one not judged
    assert row["dev_ratio_oracle_median"] == pytest.approx(1.05)  # of 0.9, 1.0, 1.1, 1.3
    text = "x\n<!-- headline begin -->\n| a |\n<!-- headline end -->\ny"
    assert headline_block(text) == "<!-- headline begin -->\n| a |\n<!-- headline end -->"


def test_an_intermittent_fault_counts_once_per_run_from_its_first_onset() -> None:
    """Three spells of one thruster in one run (isolated only in the second, 2 s after its
    onset at 100 s) are one fault isolated 72 s after the first onset at 30 s; another
    thruster's fault in the same run, and the same thruster in another run, stay their
    own; a run whose spells were never isolated is one fault never isolated."""
    from ftcap_hil.report.campaign_sweep import faults_per_run, headline_rows

    def spell(key: str, thruster: int, onset: float, delay: float | None) -> dict:
        return {**_fault("bf3", delay, kind="intermittent"), "key": key,
                "thruster": thruster, "onset_s": onset}  # fmt: skip

    faults = [spell("a", 1, 30.0, None), spell("a", 1, 100.0, 2.0), spell("a", 1, 170.0, 0.0),
              spell("a", 2, 50.0, 1.0), spell("b", 1, 30.0, 4.0),
              spell("c", 1, 30.0, None), spell("c", 1, 90.0, None)]  # fmt: skip
    merged = {(f["key"], f["thruster"]): f for f in faults_per_run(faults)}
    assert len(merged) == 4
    assert merged[("a", 1)]["spells"] == 3 and merged[("a", 1)]["isolation_delay_s"] == 72.0
    assert merged[("a", 1)]["onset_s"] == 30.0
    assert merged[("a", 2)]["isolation_delay_s"] == 1.0 and merged[("a", 2)]["spells"] == 1
    assert merged[("c", 1)]["isolation_delay_s"] is None
    (row,) = headline_rows([_run("bf3", 1.0, 0)], faults)
    assert row["faults"] == 4 and row["isolated_5s"] == 0.5 and row["never"] == 0.25
