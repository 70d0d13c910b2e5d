"""Which thrusters the fused mode leaves out of the dither (core/evidence.py): a thruster
whose drive reports fresh telemetry is judged by its drive and not dithered, unless a
silent drive's thruster needs the motion's evidence: the null-space dither then runs on
every live thruster, until the motion's recent data determine the silent one, once per
silence (core/cycle.py)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ftcap_hil.core.estimation.config import Estimate
from ftcap_hil.core.estimation.decisions import Decision
from ftcap_hil.core.estimation.shaft_types import Hypothesis, ShaftVerdict
from ftcap_hil.core.estimation.stages import StageOutput
from ftcap_hil.core.evidence import Evidence, apply_evidence

M = 4
B = np.array([[1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0], [0.3, -0.3, 0.5, -0.5]])
HEALTHY, SILENT = Hypothesis.HEALTHY, Hypothesis.TELEMETRY_LOST


def _verdict(fresh: list[bool]) -> ShaftVerdict:
    ones, nan = np.ones(M), np.full(M, np.nan)
    hyp = tuple(HEALTHY if f else SILENT for f in fresh)
    return ShaftVerdict(
        hyp, ones, nan, nan, np.array(fresh), np.zeros(M, dtype=bool), np.zeros(M), nan
    )


def _stage(observable: list[bool] | None = None, removed: list[bool] | None = None) -> StageOutput:
    no = np.zeros(M, dtype=bool)
    gone = np.array(removed or [False] * M)
    dec = Decision(
        np.where(gone, 0.0, 1.0), np.zeros(M), np.zeros(3), no, gone, gone, no,
        np.array(observable or [True] * M),
    )  # fmt: skip
    std = np.where(np.array(observable or [True] * M), 0.05, 0.2)  # observable_std 0.1
    est = Estimate(np.where(gone, 0.0, 1.0), np.zeros(3), np.zeros(M), delta_std=std)
    return StageOutput(est, dec.delta_alloc, np.zeros(3), gone, dec)


def _undithered(
    fresh: list[bool], explore: list[bool] | None, removed: list[bool] | None = None,
    dead: list[bool] | None = None, motion: bool = True,
) -> list[bool]:  # fmt: skip
    wanted = None if explore is None else np.array(explore)
    ev = Evidence.of(M, dead=dead).with_shaft(
        _verdict(fresh), np.zeros(M, dtype=bool), motion, explore=wanted
    )
    judged = apply_evidence(ev, _stage(removed=removed), 0.05, B)
    assert judged.no_dither is not None
    return judged.no_dither.tolist()


SILENT_3 = [True, True, False, True]  # thruster 3's drive is silent


def test_fresh_drives_judge_their_thrusters_and_are_not_dithered() -> None:
    assert _undithered([True] * 4, None) == [True] * 4
    assert _undithered(SILENT_3, [False] * 4) == SILENT_3


def test_a_silent_drive_whose_thruster_the_motion_has_yet_to_judge_dithers_every_one() -> None:
    # every live thruster dithers: one thruster alone has no null space to dither in
    assert _undithered(SILENT_3, [False, False, True, False]) == [False] * 4


def test_a_silent_thruster_already_out_or_known_dead_needs_no_dither() -> None:
    explore, out = [False, False, True, False], [False, False, True, False]
    assert _undithered(SILENT_3, explore, removed=out) == SILENT_3
    assert _undithered(SILENT_3, explore, dead=out) == SILENT_3
    # the drives alone decide: the motion's evidence is not asked for
    assert _undithered(SILENT_3, explore, motion=False) == SILENT_3


def test_the_core_asks_for_the_dither_once_per_silence() -> None:
    """Silent and not determined (delta_hat's std over the estimator's observable_std):
    explore; determined once: not again while silent, even when it grows again; fresh,
    then silent anew: explore again."""
    from ftcap_hil.config.scenario import load_scenario
    from ftcap_hil.core.cycle import FtcapCore

    sc = load_scenario("paper-4.2-ex1")
    core = FtcapCore(sc.B, sc.thrusters, sc.dt_s, plant=sc.plant)
    unknown, known = [True, True, False, True], [True] * 4
    steps = [
        (SILENT_3, unknown, [False] * 4),  # the start: thruster 3's drive has not spoken yet
        ([True] * 4, unknown, [False] * 4),
        (SILENT_3, unknown, [False, False, True, False]),
        (SILENT_3, known, [False] * 4),
        (SILENT_3, unknown, [False] * 4),
        ([True] * 4, unknown, [False] * 4),
        (SILENT_3, unknown, [False, False, True, False]),
    ]
    for fresh, observable, wanted in steps:
        out = _stage(observable)
        core._drives_back(_verdict(fresh), out)  # as _with_drives: who has spoken, first
        assert core._explore(out, _verdict(fresh)).tolist() == wanted


def test_a_silent_thruster_is_judged_on_the_information_since_its_drive_fell_silent() -> None:
    """With the Kalman stage's decision: a thruster the motion knew well before its drive
    fell silent (its posterior's std 0.05) is not judged by that. Only the Fisher
    information of the samples taken after the fall counts (on cycles that bring one): the
    dither goes on until it says the thruster still pushes (delta_hat - z_flag s above
    removal_threshold: at delta_hat 1, s under 0.175, 33 units) or, whatever the estimate,
    s under observable_std (100 units); then no more until the next silence, which starts
    from nothing again."""
    from ftcap_hil.config.scenario import load_scenario
    from ftcap_hil.core.cycle import FtcapCore

    sc = load_scenario("paper-4.2-ex1")
    core = FtcapCore(sc.B, sc.thrusters, sc.dt_s, plant=sc.plant)
    explore_3 = [False, False, True, False]

    def cycle(
        fresh: list[bool], info_3: float, sampled: bool = True, d3: float = 1.0
    ) -> list[bool]:
        out = _stage()  # std 0.05 everywhere: the posterior is sure of every thruster
        assert out.decision is not None
        dec = dataclasses.replace(out.decision, info=np.array([50.0, 50.0, info_3, 50.0]))
        est = dataclasses.replace(out.estimate, delta_hat=np.array([1.0, 1.0, d3, 1.0]))
        out = dataclasses.replace(out, decision=dec, estimate=est)
        core._drives_back(_verdict(fresh), out)
        return core._explore(out, _verdict(fresh), sampled).tolist()

    assert cycle([True] * 4, 500.0) == [False] * 4  # information before the fall: not counted
    assert cycle(SILENT_3, 60.0) == explore_3  # the fall's own sample: not counted either
    assert cycle(SILENT_3, 15.0) == explore_3  # 15 since the fall: s 0.26
    assert cycle(SILENT_3, 60.0, sampled=False) == explore_3  # no new sample: nothing gained
    assert cycle(SILENT_3, 15.0) == explore_3  # 30: 1 - 4 x 0.183 = 0.27, not above 0.3
    assert cycle(SILENT_3, 15.0) == [False] * 4  # 45: 1 - 4 x 0.149 = 0.40: it pushes
    assert cycle(SILENT_3, 0.0) == [False] * 4  # and stays judged while silent
    assert cycle([True] * 4, 0.0) == [False] * 4
    # a new silence starts from nothing; a loss suspected: on to observable_std
    assert cycle(SILENT_3, 60.0, d3=0.6) == explore_3
    assert cycle(SILENT_3, 60.0, d3=0.6) == explore_3  # 60: 0.6 - 4 x 0.129 < 0.3
    assert cycle(SILENT_3, 30.0, d3=0.6) == explore_3  # 90: s 0.105
    assert cycle(SILENT_3, 10.0, d3=0.6) == [False] * 4  # 100: s 0.1, observable_std


def test_a_silent_drive_that_speaks_again_healthy_drops_what_the_motion_learnt() -> None:
    """While thruster 3's drive was silent the motion judged it dead and removed it; its
    drive reports a healthy shaft again: the motion's opinion of it is dropped (delta 1 at
    its prior variance, unflagged, back in the allocation), the others' kept. In a second
    silence of 3 the motion comes to hold a loss against thruster 2, whose drive reports a
    healthy shaft: that is dropped too when 3 speaks again (3's loss charged to its
    neighbour), while thruster 1's loss, held since before either silence, is kept."""
    from ftcap_hil.config.scenario import load_scenario
    from ftcap_hil.core.cycle import FtcapCore
    from ftcap_hil.core.estimation.stages import KalmanStage

    sc = load_scenario("paper-4.2-ex1")
    core = FtcapCore(sc.B, sc.thrusters, sc.dt_s, plant=sc.plant)
    stage = core.stage
    assert isinstance(stage, KalmanStage)
    kf, dec = stage.filter, stage._decider
    ks = kf._ks
    prior = kf.P[ks + 2, ks + 2]
    kf.z[ks : ks + 4] = [0.7, 1.0, 0.0, 1.0]
    kf.P[ks + 2, ks + 2], kf.P[ks + 2, ks] = 1e-4, 1e-5
    dec._faulty[:] = dec._removed[:] = [True, False, True, False]
    before = _stage(removed=[True, False, True, False])
    core._drives_back(_verdict(SILENT_3), before)  # the start: 3 has not spoken
    core._drives_back(_verdict([True] * 4), before)
    assert kf.z[ks + 2] == 0.0
    core._drives_back(_verdict(SILENT_3), before)  # spoken, then silent: nothing dropped yet
    assert kf.z[ks + 2] == 0.0
    core._drives_back(_verdict([True] * 4), before)  # it speaks again, healthy
    assert kf.z[ks : ks + 4].tolist() == [0.7, 1.0, 1.0, 1.0]
    assert kf.P[ks + 2, ks + 2] == prior and kf.P[ks + 2, ks] == 0.0
    assert dec._faulty.tolist() == dec._removed.tolist() == [True, False, False, False]
    after = _stage(removed=[True, False, False, False])
    core._drives_back(_verdict([True] * 4), after)  # fresh all along since: nothing more
    assert dec._faulty.tolist() == [True, False, False, False]

    core._drives_back(_verdict(SILENT_3), after)  # a second silence of 3
    kf.z[ks + 1], dec._faulty[1] = 0.5, True  # the motion charges a loss to thruster 2
    charged = dataclasses.replace(after, delta_alloc=np.array([0.0, 0.5, 1.0, 1.0]))
    core._drives_back(_verdict(SILENT_3), charged)
    assert kf.z[ks + 1] == 0.5
    core._drives_back(_verdict([True] * 4), charged)  # 3 speaks again
    assert kf.z[ks : ks + 4].tolist() == [0.7, 1.0, 1.0, 1.0]
    assert dec._faulty.tolist() == [True, False, False, False]
