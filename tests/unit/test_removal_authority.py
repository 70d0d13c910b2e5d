"""A removed thruster comes back when the others cannot meet the demand without it
(FtcapCore._unremove_if_short): removal saves effort, it must not cost authority.

The stage is replaced by one that reports a fixed decision, so the test is about the cycle's
use of it: the CyberShip II preset, the starboard propeller (2) estimated at 0.4 and removed,
as the realistic campaign's stuck-port-propeller run did (its boat was pushed 46 m away).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.cycle import SHORT_FRACTION, FtcapCore
from ftcap_hil.core.estimation.config import Estimate
from ftcap_hil.core.estimation.decisions import Decision
from ftcap_hil.core.estimation.stages import StageOutput
from ftcap_hil.runtime.offline import told_sensor_noise

REMOVED = 1  # starboard main propeller, 0-based
DELTA_HAT = 0.4


class FixedStage:
    """Always the same decision: thruster REMOVED faulty, estimated at DELTA_HAT, removed."""

    def __init__(self, m: int, k: int, removed: bool = True) -> None:
        d = np.ones(m)
        d[REMOVED] = DELTA_HAT
        flags = np.zeros(m, dtype=bool)
        flags[REMOVED] = True
        alloc = np.where(flags, 0.0 if removed else DELTA_HAT, 1.0)
        self.out = StageOutput(
            Estimate(d, np.zeros(k), np.zeros(m)),
            alloc,
            np.zeros(k),
            flags,
            Decision(
                alloc,
                np.zeros(m),
                np.zeros(k),
                flags,
                flags & removed,
                flags,
                np.zeros(m, dtype=bool),
                np.ones(m, dtype=bool),
            ),
        )

    def update(self, *_: Any) -> StageOutput:
        return self.out


def core_with(stage: FixedStage) -> FtcapCore:
    sc = load_scenario("cybership2-station")
    core = FtcapCore(sc.B, sc.thrusters, sc.dt_s, told_sensor_noise(sc).core, sc.plant)
    core.stage = stage  # type: ignore[assignment]
    return core


def settle(core: FtcapCore, tau_d: np.ndarray, cycles: int = 200) -> Any:
    for _ in range(cycles):  # rate limits: let the command reach its target
        r = core.step(tau_d, None)
    return r


def without_fix() -> FtcapCore:
    core = core_with(FixedStage(5, 3))
    core._unremove_if_short = lambda alloc, *_: alloc  # type: ignore[method-assign]
    return core


def test_a_removed_thruster_returns_when_the_demand_is_not_met_without_it() -> None:
    core = core_with(FixedStage(5, 3))
    astern = np.array([-0.6 * core.scale[0], 0.0, 0.0])  # needs both mains astern
    r, ref = settle(core, astern), settle(without_fix(), astern)
    short, ref_short = (np.abs(x.allocation.unallocated) / core.scale for x in (r, ref))
    assert ref_short.max() > 4 * SHORT_FRACTION, ref_short  # the case: short without it
    assert abs(ref.u[REMOVED]) < 0.2 * core.u_range[REMOVED], ref.u  # a probe at most
    assert r.u[REMOVED] < -0.5 * core.u_range[REMOVED], r.u  # back, pushing astern
    assert np.linalg.norm(short) < 0.5 * np.linalg.norm(ref_short), (short, ref_short)
    assert r.faulty[REMOVED]  # still reported faulty: only the allocation changed


def test_a_removed_thruster_stays_out_while_the_others_meet_the_demand() -> None:
    core = core_with(FixedStage(5, 3))
    gentle = np.array([-0.1 * core.scale[0], 0.0, 0.0])
    r = settle(core, gentle)
    ref = settle(without_fix(), gentle)
    np.testing.assert_allclose(r.u, ref.u, atol=1e-9)
    assert np.abs(r.allocation.unallocated / core.scale).max() <= SHORT_FRACTION


def test_nothing_changes_when_nothing_is_removed() -> None:
    core = core_with(FixedStage(5, 3, removed=False))
    far = np.array([-2.0 * core.scale[0], 0.0, 0.0])  # unattainable for anyone
    r = settle(core, far)
    ref_core = core_with(FixedStage(5, 3, removed=False))
    ref_core._unremove_if_short = lambda alloc, *_: alloc  # type: ignore[method-assign]
    np.testing.assert_allclose(r.u, settle(ref_core, far).u, atol=1e-9)
