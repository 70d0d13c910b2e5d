"""Campaign metrics against hand-computed values on synthetic run records.

Each record is built column by column (the offline simulator's columns plus faulty_i and
dead_i) on the paper's vessel with T_s = 0.1 s, so every delay below is a whole number of
cycles and can be written down by hand.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from ftcap_hil.config.campaign import HarmBasis, MetricParams
from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.estimation.shaft_types import HYPOTHESIS_CODES, DriveModel, Hypothesis
from ftcap_hil.core.faults import Cause, FaultEvent, FaultSchedule
from ftcap_hil.core.scenario import Scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.report.campaign_metrics import (
    Reference,
    classify,
    episodes,
    first_held,
    reference_of,
    run_metrics,
)
from ftcap_hil.report.campaign_report import cell
from ftcap_hil.report.campaign_summary import derive, fault_groups, fault_rows, run_groups
from ftcap_hil.report.records import RunRecord, column_names
from ftcap_hil.runtime.offline import run_mode

DT = 0.1
PARAMS = MetricParams()


def _scenario(duration_s: float, dt_s: float = DT) -> Scenario:
    sc = load_scenario("paper-4.2-ex1")
    return dataclasses.replace(sc, dt_s=dt_s, duration_s=duration_s)


class Synthetic:
    """A record of n cycles: healthy truth, perfect estimates, nothing flagged, at rest."""

    def __init__(self, duration_s: float, dt_s: float = DT) -> None:
        self.sc = _scenario(duration_s, dt_s)
        self.n = self.sc.steps
        self.t = np.arange(self.n) * dt_s
        self.c: dict[str, Any] = {k: np.zeros(self.n) for k in column_names(self.sc)}
        self.c["t"] = self.t.copy()
        for i in range(1, 5):
            self.c[f"delta_{i}"][:] = 1.0
            self.c[f"delta_hat_{i}"][:] = 1.0

    def at(self, t0: float, t1: float = math.inf) -> np.ndarray:
        """Cycle mask t0 <= t < t1 (a tiny margin against float rounding of k * dt)."""
        return (self.t >= t0 - 1e-9) & (self.t < t1 - 1e-9)

    def set(self, name: str, t0: float, t1: float, value: float) -> None:
        self.c[name][self.at(t0, t1)] = value

    def record(self) -> RunRecord:
        return RunRecord(self.sc, "ftcap", self.c)


def _dead_thruster_2(rec: Synthetic) -> None:
    """Thruster 2 dead from 10 s on; the estimate follows at once."""
    rec.set("delta_2", 10.0, math.inf, 0.0)
    rec.set("delta_hat_2", 10.0, math.inf, 0.0)


def test_a_flag_that_rises_1_5_s_after_the_onset_is_a_detection_delay_of_1_5_s() -> None:
    rec = Synthetic(60.0)
    _dead_thruster_2(rec)
    rec.set("faulty_2", 11.5, math.inf, 1.0)
    rec.set("dead_2", 12.0, math.inf, 1.0)
    (fault,) = run_metrics(rec.record(), None, PARAMS)["faults"]
    assert fault["thruster"] == 2 and fault["kind"] == "dead" and fault["detectable"]
    assert fault["onset_s"] == pytest.approx(10.0)
    assert fault["detection_delay_s"] == pytest.approx(1.5)
    assert fault["removal_delay_s"] == pytest.approx(2.0)
    assert fault["isolation_delay_s"] == pytest.approx(1.5)
    assert fault["correct_isolation"] is True
    assert fault["ended"] is False and fault["recovery_s"] is None


def test_isolation_waits_until_no_healthy_thruster_is_flagged() -> None:
    rec = Synthetic(60.0)
    _dead_thruster_2(rec)
    rec.set("faulty_2", 11.5, math.inf, 1.0)
    rec.set("faulty_4", 11.0, 13.0, 1.0)  # a healthy one flagged by mistake meanwhile
    out = run_metrics(rec.record(), None, PARAMS)
    (fault,) = out["faults"]
    assert fault["detection_delay_s"] == pytest.approx(1.5)
    assert fault["isolation_delay_s"] == pytest.approx(3.0)
    assert out["false_alarms"] == 1
    assert out["healthy_flagged_s"] == pytest.approx(2.0)


def test_a_fault_never_isolated_at_the_end_is_not_a_correct_isolation() -> None:
    rec = Synthetic(60.0)
    _dead_thruster_2(rec)
    rec.set("faulty_2", 11.0, math.inf, 1.0)
    rec.set("faulty_1", 40.0, math.inf, 1.0)  # the last quarter (47.5-60 s) has a healthy flag
    (fault,) = run_metrics(rec.record(), None, PARAMS)["faults"]
    assert fault["isolation_delay_s"] == pytest.approx(1.0)
    assert fault["correct_isolation"] is False


def test_a_healthy_thruster_flagged_for_10_s_in_1_h_is_1_false_alarm_per_h() -> None:
    rec = Synthetic(3600.0, dt_s=1.0)
    rec.set("faulty_3", 1000.0, 1010.0, 1.0)
    rec.set("dead_3", 1002.0, 1007.0, 1.0)
    rec.set("delta_hat_3", 1000.0, 1010.0, 0.05)
    out = run_metrics(rec.record(), None, PARAMS)
    assert out["faults"] == []
    assert out["healthy_hours"] == pytest.approx(1.0)
    assert out["false_alarms"] == 1 and out["false_removals"] == 1
    assert out["false_alarm_rate_per_h"] == pytest.approx(1.0)
    assert out["healthy_flagged_s"] == pytest.approx(10.0)
    assert out["healthy_removed_s"] == pytest.approx(5.0)
    assert out["healthy_flagged_frac"] == pytest.approx(10.0 / (4 * 3600.0))
    assert out["healthy_delta_hat_min"] == pytest.approx(0.05)


def test_time_to_estimate_and_errors_after_convergence() -> None:
    rec = Synthetic(60.0)
    rec.set("delta_1", 10.0, math.inf, 0.5)
    # the estimate: 1 until 12 s, 0.58 (error 0.08) from 12 to 12.5 s, 0.75 from 12.5 to 14
    # s (error 0.25), then 0.52 (error 0.02) for good: within 0.1 for 2 s only from 14 s
    rec.set("delta_hat_1", 12.0, 12.5, 0.58)
    rec.set("delta_hat_1", 12.5, 14.0, 0.75)
    rec.set("delta_hat_1", 14.0, math.inf, 0.52)
    rec.set("faulty_1", 12.0, math.inf, 1.0)
    rec.set("f_hat_1", 0.0, math.inf, 0.004)
    (fault,) = run_metrics(rec.record(), None, PARAMS)["faults"]
    assert fault["kind"] == "partial"
    assert fault["converge_s"] == pytest.approx(4.0)
    assert fault["delta_error"] == pytest.approx(0.02)
    assert fault["bias_error"] == pytest.approx(0.004)


def test_recovery_after_an_intermittent_fault_ends() -> None:
    rec = Synthetic(60.0)
    rec.set("delta_2", 10.0, 20.0, 0.0)
    rec.set("delta_hat_2", 10.0, 23.0, 0.0)
    rec.set("dead_2", 10.5, 23.0, 1.0)
    rec.set("faulty_2", 11.0, 25.0, 1.0)
    out = run_metrics(rec.record(), None, PARAMS, kinds={1: "intermittent"})
    (fault,) = out["faults"]
    assert fault["kind"] == "intermittent" and fault["ended"] is True
    assert fault["end_s"] == pytest.approx(20.0)
    assert fault["recovery_s"] == pytest.approx(3.0)
    assert fault["recovery_unflag_s"] == pytest.approx(5.0)
    # from 20 s thruster 2 is healthy: its 5 s of flag and 3 s of removal after the fault
    # are false (the off-spell of an intermittent fault), no rising edge though
    assert out["healthy_hours"] == pytest.approx((4 * 60.0 - 10.0) / 4 / 3600)
    assert out["healthy_flagged_s"] == pytest.approx(5.0)
    assert out["healthy_removed_s"] == pytest.approx(3.0)
    assert out["false_alarms"] == 0 and out["removal_switches"] == 1  # back in at 23 s
    rec.set("faulty_2", 40.0, 41.0, 1.0)  # a new flag is a false alarm
    out = run_metrics(rec.record(), None, PARAMS, kinds={1: "intermittent"})
    assert out["false_alarms"] == 1 and out["healthy_flagged_s"] == pytest.approx(6.0)


def test_off_spells_flagged_throughout_are_false_and_no_recovery() -> None:
    """An intermittent fault (dead 5 s, healthy 5 s) whose flag never clears: under the old
    definition every off-spell was 'recovering' and none of it counted; now each off-spell
    is 5 s flagged on a healthy thruster, and no episode recovers."""
    rec = Synthetic(60.0)
    for k in range(5):
        rec.set("delta_2", 10.0 + 10 * k, 15.0 + 10 * k, 0.0)
    rec.set("faulty_2", 10.5, math.inf, 1.0)
    rec.set("delta_hat_2", 10.5, math.inf, 0.0)
    out = run_metrics(rec.record(), None, PARAMS, kinds={1: "intermittent"})
    assert len(out["faults"]) == 5
    ended = [f for f in out["faults"] if f["ended"]]
    assert ended and all(f["recovery_s"] is None for f in ended)
    assert out["healthy_flagged_s"] == pytest.approx(5 * 5.0 - 0.0)  # 15-20, ..., 55-60
    assert out["false_alarms"] == 0  # one rising edge, during the first dead spell


def test_recovery_needs_the_true_effectiveness_not_only_the_allocation() -> None:
    """A fault that ends: the thruster is back in the allocation at 21 s, but the estimate
    sits at 0.5 (the allocator uses half of it) until 30 s: recovered at 30 s, not 21 s."""
    rec = Synthetic(60.0)
    rec.set("delta_2", 10.0, 20.0, 0.0)
    rec.set("delta_hat_2", 10.0, 21.0, 0.0)
    rec.set("delta_hat_2", 21.0, 30.0, 0.5)
    rec.set("dead_2", 10.5, 21.0, 1.0)
    (fault,) = run_metrics(rec.record(), None, PARAMS)["faults"]
    assert fault["recovery_s"] == pytest.approx(10.0)


def test_a_chattering_healthy_thruster_counts_switches_and_merged_episodes() -> None:
    """A healthy thruster removed and returned 40 times, 0.3 s in, 0.7 s out (1 s period):
    12 s removed in 60 s is a small time share, but 80 removal switches; the 40 flags that
    go with it are 40 false alarms and 1 false-alarm episode (each rise within 2 s of the
    last fall), and a flag 10 s after the last is a second episode."""
    rec = Synthetic(60.0)
    for k in range(40):
        rec.set("dead_3", 10.0 + k, 10.3 + k, 1.0)
        rec.set("faulty_3", 10.0 + k, 10.3 + k, 1.0)
    rec.set("faulty_3", 59.0, 59.5, 1.0)
    out = run_metrics(rec.record(), None, PARAMS)
    assert out["removal_switches"] == 80
    assert out["false_alarms"] == 41 and out["false_alarm_episodes"] == 2
    assert out["healthy_removed_s"] == pytest.approx(12.0)
    hours = 60.0 / 3600
    assert out["removal_switches_per_h"] == pytest.approx(80 / hours)


def test_a_thruster_that_never_recovers_is_removed_on_healthy_time() -> None:
    rec = Synthetic(60.0)
    rec.set("delta_2", 10.0, 20.0, 0.0)
    rec.set("dead_2", 10.5, math.inf, 1.0)
    rec.set("faulty_1", 30.0, 31.0, 1.0)  # another thruster's false alarm counts too
    out = run_metrics(rec.record(), None, PARAMS)
    assert out["faults"][0]["recovery_s"] is None
    assert out["healthy_removed_s"] == pytest.approx(40.0) and out["false_alarms"] == 1
    assert out["false_removals"] == 0  # it was removed while faulty
    assert out["healthy_hours"] == pytest.approx((4 * 60.0 - 10.0) / 4 / 3600)


def test_deviation_from_the_reference_and_the_used_test() -> None:
    rec = Synthetic(60.0)
    _dead_thruster_2(rec)
    rec.c["north"][rec.at(10.0)] = 0.03
    rec.c["east"][rec.at(10.0)] = 0.04  # 5 cm from the reference from 10 s on
    u_ref = np.zeros((rec.n, 4))
    u_ref[rec.at(10.0, 13.0), 1] = 0.05  # half the range for 3 of the first 5 s: used
    ref = Reference(np.zeros((rec.n, 2)), u_ref)
    out = run_metrics(rec.record(), ref, PARAMS)
    assert out["deviation_max"] == pytest.approx(0.05)
    assert out["deviation_rms"] == pytest.approx(0.05 * math.sqrt(50 / 60))
    (fault,) = out["faults"]
    assert fault["used"] is True and fault["deviation_rms"] == pytest.approx(0.05)
    u_ref[rec.at(11.0, 13.0), 1] = 0.0  # 1 s of 5: not used
    assert run_metrics(rec.record(), ref, PARAMS)["faults"][0]["used"] is False


def _row(
    variant: str, phase_max: list[float], rms: float, healthy: bool = False,
    tracking: list[float] | None = None,
) -> dict:  # fmt: skip
    """A run row; ``phase_max``: per phase the deviation max (its RMS half of it), and the
    tracking error max too unless ``tracking`` gives it."""
    mode = variant if variant in ("none", "cap", "oracle") else "ftcap"
    trk = phase_max if tracking is None else tracking
    phases = [
        {"start_s": 10.0 * j, "end_s": 10.0 * (j + 1), "deviation_max": v, "deviation_rms": v / 2,
         "tracking_max": w, "tracking_rms": w / 2}
        for j, (v, w) in enumerate(zip(phase_max, trk, strict=True))
    ]  # fmt: skip
    return {
        "key": f"c/{variant}",
        "case": "c",
        "variant": variant,
        "mode": mode,
        "status": "ok",
        "healthy": healthy,
        "length_m": 0.3,
        "phases": phases,
        "deviation_rms": rms,
        "replay": "ftcap-hil simulate x",
    }


DEVIATION = dataclasses.replace(PARAMS, harm_basis=HarmBasis.DEVIATION)


def test_harm_is_a_phase_worse_than_1_05_x_the_better_of_cap_and_the_oracle() -> None:
    """On the deviation from the fault-free run (harm_basis = deviation)."""
    rows = [
        _row("cap", [0.01, 0.02, 0.001, 0.01], 0.02),
        _row("oracle", [0.005, 0.01, 0.0, 0.02], 0.01),
        # 1.05 x CAP exactly (no harm); 1.5 x CAP (harm); 2.9 x CAP, 2.9 mm: harm (the old
        # floor, 1 % of the 0.3 m hull, hid it); 1.5 x CAP but under 1.05 x the oracle: none
        _row("ftcap", [0.0105, 0.03, 0.0029, 0.015], 0.03),
    ]
    out = {r["variant"]: r for r in derive(rows, DEVIATION)}
    assert out["ftcap"]["harm"] is True and out["ftcap"]["harm_phases"] == [1, 2]
    assert out["ftcap"]["dev_ratio_oracle"] == pytest.approx(3.0)
    assert out["ftcap"]["dev_ratio_cap"] == pytest.approx(1.5)
    detail = out["ftcap"]["harm_detail"][3]
    assert detail["ratio_cap"] == pytest.approx(1.5)
    assert detail["ratio_oracle"] == pytest.approx(0.75)
    assert "harm" not in out["cap"]  # CAP is the reference
    healthy = derive([_row("ftcap", [0.0031, 0.0], 0.001, healthy=True)], DEVIATION)[0]
    assert healthy["harm"] is True and healthy["harm_phases"] == [0]  # against CAP = 0
    assert healthy["dev_ratio_cap"] is None  # no CAP run, and its deviation would be 0


def test_harm_on_tracking_does_not_count_a_better_track_away_from_the_fault_free_run() -> None:
    """A healthy case with a model error: the fault-free run (CAP's allocation) tracks to
    31 mm; F-TCAP, correcting the error, strays 16 mm from that run and tracks to 26 mm
    (measured on CyberShip II in a 1.25 m/s current): harm on the deviation, none on the
    tracking error (the default basis). 1.2x the fault-free run's tracking is harm."""
    none = _row("none", [0.0], 0.0, healthy=True, tracking=[0.031])
    better = _row("ftcap", [0.016], 0.01, healthy=True, tracking=[0.026])
    worse = {**_row("ftcap", [0.016], 0.01, healthy=True, tracking=[0.0372]), "key": "c/w",
             "variant": "ftcap-w"}  # fmt: skip
    out = {r["variant"]: r for r in derive([none, better, worse], PARAMS)}
    assert out["ftcap"]["harm"] is False
    assert out["ftcap"]["harm_detail"][0]["ratio_cap"] == pytest.approx(0.026 / 0.031)
    assert out["ftcap-w"]["harm"] is True
    assert derive([none, better], DEVIATION)[1]["harm"] is True  # the old basis's verdict


def test_harm_unknown_when_the_cap_run_failed() -> None:
    cap = {**_row("cap", [0.01], 0.01), "status": "failed"}
    ftcap = derive([cap, _row("ftcap", [0.05], 0.05)], PARAMS)[1]
    assert ftcap["harm"] is None and ftcap["dev_ratio_cap"] is None


def test_percentiles_count_a_miss_as_never() -> None:
    base = {
        "key": "k",
        "case": "c",
        "scenario": "s",
        "seed": 0,
        "variant": "ftcap",
        "mode": "ftcap",
        "kind": "dead",
        "status": "ok",
    }
    faults = [
        {
            "kind": "dead",
            "detectable": True,
            "used": True,
            "detection_delay_s": d,
            "isolation_delay_s": d,
            "removal_delay_s": d,
            "correct_isolation": d is not None,
            "delta_error": 0.0,
            "converge_s": d,
            "ended": False,
            "recovery_s": None,
        }
        for d in (1.0, 2.0, None)
    ]
    groups = {g["kind"]: g for g in fault_groups(fault_rows([{**base, "faults": faults}]))}
    g = groups["dead"]
    assert g["detection_rate"] == pytest.approx(2 / 3)
    assert g["detection_delay_median"] == pytest.approx(2.0)
    assert g["detection_delay_p95"] == math.inf
    assert g["correct_isolation_rate"] == pytest.approx(2 / 3)
    assert g["recovery_median"] is None  # no fault ended
    assert groups["all"]["faults"] == 3


def test_run_groups_pool_false_alarms_over_healthy_hours() -> None:
    rows = [
        {
            "key": f"k{j}",
            "case": f"c{j}",
            "variant": "ftcap",
            "mode": "ftcap",
            "kind": "healthy",
            "status": "ok",
            "duration_s": 3600.0,
            "healthy_hours": 1.0,
            "healthy_thruster_s": 4 * 3600.0,
            "false_alarms": j,
            "healthy_flagged_s": 36.0,
            "healthy_removed_s": 0.0,
            "deviation_rms": 0.0,
        }
        for j in range(3)
    ]
    (g, _) = [g for g in run_groups(rows) if g["kind"] in ("healthy", "all")]
    assert g["runs"] == 3 and g["false_alarm_rate_per_h"] == pytest.approx(1.0)
    assert g["healthy_flagged_frac"] == pytest.approx(36.0 / (4 * 3600.0))


def test_run_groups_give_episode_and_switch_rates_with_their_intervals() -> None:
    """3 healthy hours, 3 false-alarm episodes, 0 removal switches: 1.0 /h in the exact
    Poisson interval [0.206, 2.92] /h, and 0 /h with an upper bound of 3.69 / 3 h."""
    rows = [
        {
            "key": f"k{j}", "case": f"c{j}", "variant": "ftcap", "mode": "ftcap",
            "kind": "healthy", "status": "ok", "duration_s": 3600.0, "healthy_hours": 1.0,
            "healthy_thruster_s": 4 * 3600.0, "false_alarms": 5, "false_alarm_episodes": 1,
            "removal_switches": 0, "healthy_flagged_s": 0.0, "healthy_removed_s": 0.0,
            "deviation_rms": 0.0, "harm": j == 0,
        }
        for j in range(3)
    ]  # fmt: skip
    (g,) = [g for g in run_groups(rows) if g["kind"] == "healthy"]
    assert g["false_alarm_episodes_per_h"] == pytest.approx(1.0)
    assert g["false_alarm_episodes_per_h_lo"] == pytest.approx(0.2063, abs=1e-3)
    assert g["false_alarm_episodes_per_h_hi"] == pytest.approx(2.9224, abs=1e-3)
    assert g["false_alarm_episodes_per_h_n"] == 3
    assert g["removal_switches_per_h"] == 0.0
    assert g["removal_switches_per_h_hi"] == pytest.approx(3.6889 / 3, abs=1e-3)
    assert g["harm_share"] == pytest.approx(1 / 3) and g["harm_share_n"] == 3
    assert cell(g, "false_alarm_episodes_per_h") == "1 [0.206, 2.92] (3)"
    assert cell(g, "harm_share") == "33.3 % [6.15 %, 79.2 %] (3)"
    assert cell(g, "runs") == "3"


def test_fault_groups_give_isolation_shares_and_recovery() -> None:
    """Four dead faults isolated after 2 s, 10 s, 40 s and never; two of them ended, one
    came back: within 5 s 1/4, within 30 s 2/4, never 1/4, recovered 1/2."""
    base = {"key": "k", "case": "c", "scenario": "s", "seed": 0, "variant": "ftcap",
            "mode": "ftcap", "kind": "dead", "status": "ok"}  # fmt: skip
    faults = [
        {"kind": "dead", "detectable": True, "used": True, "detection_delay_s": d,
         "isolation_delay_s": d, "removal_delay_s": d, "correct_isolation": d is not None,
         "delta_error": 0.0, "converge_s": d, "ended": ended, "recovery_s": back}
        for d, ended, back in ((2.0, True, 1.5), (10.0, True, None), (40.0, False, None),
                               (None, False, None))
    ]  # fmt: skip
    groups = fault_groups(fault_rows([{**base, "faults": faults}]))
    (g,) = [g for g in groups if g["kind"] == "dead"]
    assert g["isolated_5s_share"] == pytest.approx(0.25)
    assert g["isolated_30s_share"] == pytest.approx(0.5)
    assert g["never_isolated_share"] == pytest.approx(0.25) and g["never_isolated_share_n"] == 4
    assert g["recovered_share"] == pytest.approx(0.5) and g["recovered_share_n"] == 2
    assert g["recovery_median"] == math.inf  # one of the two never came back


def test_first_held_and_classify() -> None:
    mask = np.array([0, 1, 1, 0, 1, 1, 1, 1, 0, 1], dtype=bool)
    assert first_held(mask, 0, 10, 3) == 4
    assert first_held(mask, 0, 10, 2) == 1
    assert first_held(mask, 0, 10, 5) == 9  # the run reaching the end counts
    assert first_held(mask, 0, 8, 5) == 4
    assert first_held(np.zeros(5, dtype=bool), 0, 5, 1) is None
    z = np.zeros(3)
    assert classify(z, z) == "dead" and classify(z, z + 0.01) == "stuck"
    assert classify(z + 0.5, z) == "partial" and classify(z + 1.0, z - 0.01) == "bias"
    assert classify(z + 0.9, z + 0.01) == "mixed"


def test_the_oracle_on_a_real_run_detects_and_isolates_at_once() -> None:
    """The same metrics on the offline simulator's record: the oracle is told the truth."""
    dead = FaultEvent(15.0, math.inf, 2, np.array(0.0), None)
    sc = dataclasses.replace(
        load_scenario("paper-4.2-ex1"), duration_s=40.0, faults=FaultSchedule(4, (dead,))
    )
    rec = run_mode(sc, Mode.ORACLE)
    out = run_metrics(rec, reference_of(run_mode(sc, Mode.NONE)), PARAMS)
    (fault,) = episodes(rec)
    assert fault.thruster == 2 and fault.kind == "dead"
    (row,) = out["faults"]
    assert row["detection_delay_s"] == 0.0 and row["isolation_delay_s"] == 0.0
    assert row["delta_error"] == 0.0 and row["correct_isolation"] is True
    assert out["false_alarms"] == 0 and out["deviation_max"] > 0.0


def _cause_row(
    cause: Cause, delta: float, verdict: Hypothesis | None, servo: bool = False,
) -> dict[str, Any]:  # fmt: skip
    """Thruster 2 (a servo if ``servo``) faulty from 10 s with ``cause`` in the schedule,
    isolated from 11 s on with ``verdict`` as its drive's hypothesis (None: no diagnosis,
    code 0)."""
    rec = Synthetic(40.0)
    event = FaultEvent(10.0, math.inf, 1, np.array(delta), None, cause=cause)
    drives = tuple(DriveModel(1.0, 0.1, is_shaft=not (servo and i == 1)) for i in range(4))
    rec.sc = dataclasses.replace(rec.sc, faults=FaultSchedule(4, (event,)), drives=drives)
    rec.set("delta_2", 10.0, math.inf, delta)
    rec.set("faulty_2", 11.0, math.inf, 1.0)
    if verdict is not None:
        rec.set("drive_2", 10.0, 11.0, HYPOTHESIS_CODES[Hypothesis.HEALTHY])
        rec.set("drive_2", 11.0, math.inf, HYPOTHESIS_CODES[verdict])
    (row,) = run_metrics(rec.record(), None, PARAMS)["faults"]
    return row


def test_a_fault_row_names_its_cause_what_the_drive_can_show_and_what_it_said() -> None:
    row = _cause_row(Cause.JAMMED, 0.0, Hypothesis.JAMMED)
    assert (row["cause"], row["drive_visible"]) == ("jammed", True)
    assert (row["drive_verdict"], row["cause_named"]) == ("jammed", True)
    # the verdict is what the drive said while isolated, not before
    row = _cause_row(Cause.DRIVE_DEAD, 0.0, Hypothesis.LOAD_GAIN)
    assert (row["drive_verdict"], row["cause_named"]) == ("load-gain", False)
    # a silent drive and a hull loss are not the drive's to see; a light weak motor neither
    assert not _cause_row(Cause.POWER_LOST, 0.0, None)["drive_visible"]
    assert not _cause_row(Cause.HULL_LOSS, 0.5, None)["drive_visible"]
    assert not _cause_row(Cause.WEAK_MOTOR, 0.8, Hypothesis.WEAK)["drive_visible"]
    assert _cause_row(Cause.WEAK_MOTOR, 0.7, Hypothesis.WEAK)["drive_visible"]
    row = _cause_row(Cause.LOST_BLADE, 0.5, None)  # no diagnosis: no verdict
    assert (row["drive_verdict"], row["cause_named"]) == (None, None)
    # a jammed servo holds its deflection and its force: a stuck verdict names it
    assert _cause_row(Cause.JAMMED, 0.0, Hypothesis.STUCK, servo=True)["cause_named"] is True
    assert _cause_row(Cause.JAMMED, 0.0, Hypothesis.STUCK)["cause_named"] is False
    assert _cause_row(Cause.JAMMED, 0.0, Hypothesis.JAMMED, servo=True)["cause_named"] is False


def test_a_weak_motor_ramp_is_timed_from_when_its_drive_can_show_it() -> None:
    """A weak motor at 0.8 from 10 s (not yet drive-visible), 0.6 from 20 s, isolated from
    21 s: visible from 10 s after the onset, isolated 1 s after that; a dead drive is
    visible from its onset."""
    rec = Synthetic(40.0)
    event = FaultEvent(10.0, math.inf, 1, np.array(0.6), None, cause=Cause.WEAK_MOTOR)
    rec.sc = dataclasses.replace(rec.sc, faults=FaultSchedule(4, (event,)))
    rec.set("delta_2", 10.0, 20.0, 0.8)
    rec.set("delta_2", 20.0, math.inf, 0.6)
    rec.set("faulty_2", 21.0, math.inf, 1.0)
    (row,) = run_metrics(rec.record(), None, PARAMS)["faults"]
    assert row["drive_visible"] and row["visible_s"] == pytest.approx(10.0)
    assert row["visible_delay_s"] == pytest.approx(1.0)
    assert row["isolation_delay_s"] == pytest.approx(11.0)
    row = _cause_row(Cause.DRIVE_DEAD, 0.0, Hypothesis.DRIVE_DEAD)
    assert row["visible_s"] == 0.0 and row["visible_delay_s"] == pytest.approx(1.0)
    assert _cause_row(Cause.POWER_LOST, 0.0, None)["visible_delay_s"] is None


def test_the_drive_visible_table_counts_a_run_once_and_its_named_causes() -> None:
    from ftcap_hil.report.campaign_sweep import drive_visible_rows

    def fault(key: str, cause: str, delay: float | None, named: bool | None) -> dict[str, Any]:
        return {"key": key, "thruster": 1, "mode": "ftcap", "variant": "ftcap",
                "scenario": "s", "cause": cause, "onset_s": 10.0, "detectable": True,
                "drive_visible": cause != "power-lost", "isolation_delay_s": 99.0,
                "visible_delay_s": delay, "cause_named": named}  # fmt: skip

    rows = drive_visible_rows(
        [fault("a", "jammed", 1.0, True), fault("b", "jammed", 3.0, False),
         fault("c", "drive-dead", None, None), fault("d", "power-lost", 0.5, True)],
        "scenario",
    )  # fmt: skip
    (row,) = rows
    assert row["faults"] == 3 and row["isolated_2s"] == pytest.approx(1 / 3)
    assert row["isolated_5s"] == pytest.approx(2 / 3) and row["never"] == pytest.approx(1 / 3)
    assert row["named"] == pytest.approx(1 / 3) and row["named_n"] == 3
    by_cause = {
        r["cause"]: r["faults"]
        for r in drive_visible_rows([fault("a", "jammed", 1.0, True)], "cause")
    }
    assert by_cause == {"jammed": 1}
