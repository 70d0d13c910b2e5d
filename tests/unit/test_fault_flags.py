"""Fault flags: hysteresis between fault_threshold and fault_clear, no flapping."""

from __future__ import annotations

import numpy as np

from ftcap_hil.core.cycle import CoreConfig, FtcapCore
from ftcap_hil.core.effectiveness.geometry import effectiveness, paper_four_thrusters
from ftcap_hil.core.estimation.config import EstimatorConfig, EstimatorKind
from ftcap_hil.core.evidence import Evidence
from ftcap_hil.core.faults import Truth
from ftcap_hil.core.status import Mode


def _oracle() -> FtcapCore:
    ths = paper_four_thrusters()
    return FtcapCore(effectiveness(ths), ths, 0.2827, CoreConfig(mode=Mode.ORACLE))


def _flag(core: FtcapCore, delta1: float, forced: np.ndarray | None = None) -> bool:
    truth = Truth(np.array([delta1, 1.0, 1.0, 1.0]), np.zeros(4))
    return bool(core.step(np.zeros(3), None, truth, evidence=Evidence.of(4, dead=forced)).faulty[0])


def test_flag_sets_below_threshold_and_clears_only_above_clear_level() -> None:
    core = _oracle()
    assert not _flag(core, 0.9)  # between the levels, never flagged: stays clear
    assert _flag(core, 0.84)
    # An estimate oscillating around a true 0.8-0.9 must not flap the flag.
    assert all(_flag(core, d) for d in (0.86, 0.90, 0.83, 0.94, 0.88))
    assert not _flag(core, 0.96)
    assert not _flag(core, 0.9)


def test_forced_dead_is_reported_faulty_without_touching_the_state() -> None:
    core = _oracle()
    forced = np.array([True, False, False, False])
    assert _flag(core, 1.0, forced)
    assert not _flag(core, 1.0)


def test_windowed_flags_wait_for_a_determined_estimate() -> None:
    ths = paper_four_thrusters()
    B = effectiveness(ths)
    cfg = CoreConfig(mode=Mode.FTCAP, estimator=EstimatorConfig(kind=EstimatorKind.WINDOWED))
    core = FtcapCore(B, ths, 0.2827, cfg)
    rng = np.random.default_rng(0)
    flags = []
    for _ in range(30):
        u = rng.uniform(-0.1, 0.1, 4)
        w = B @ (np.array([0.5, 1.0, 1.0, 1.0]) * u)  # thruster 1 at half effectiveness
        res = core.step(np.zeros(3), w, u_sample=u)
        flags.append((res.estimate.window_len, bool(res.faulty[0]), bool(res.faulty[1:].any())))
    assert all(not f for n, f, _ in flags if n < 7)  # m + k = 7 samples before any flag
    assert flags[-1][1] and not flags[-1][2]
