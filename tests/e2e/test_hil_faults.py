"""Faults injected into the simulated vessel over MAVLink and Zenoh are estimated by the
allocator while the test holds position with eq. (24) on ODOMETRY.

The allocator runs at the paper's rate (T_s = 0.2827 s, one estimator sample per T_s of
telemetry, trapezoid inversion of the sim's RK4 plant: the shipped allocator.toml); the test
sends a WRENCH_SETPOINT every 0.1 s. At station keeping the commands carry information only
through the null-space dither, which exists while four thrusters are live: thruster 1 is
weakened (Zenoh) before thruster 2 is switched off (MAVLink). The other order cannot work:
with three live thrusters for three degrees of freedom the null space is empty, nothing
excites thruster 1 and a later WEAK on it stays invisible (measured: delta_hat 0.99 for 20 s).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from bridges.mavlink.config import VESSEL_IDS
from bridges.mavlink.gcs import MavlinkGcsLink
from bridges.mavlink.vessel import FAILURE_ENABLE_PARAM, MavResult
from ftcap_hil.core.messages import FaultInjection, FaultKind
from ftcap_hil.runtime.processes import wait_until
from tests.e2e.rig import Rig, setpoints

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(180)]

TOL = 0.1  # |delta_hat - delta| for "estimated"
WEAK_WITHIN_S = 10.0  # paper rate: a restart needs m + k = 7 samples, about 2 s
OFF_WITHIN_S = 20.0  # thrusters 3 and 4 dip to ~0.78 for ~6 s after thruster 2 is lost
HOLD_POSITION_M = 0.05  # station keeping needs almost no force: measured < 0.002 m
HOLD_HEADING_RAD = 0.05


def _delta_hat(gcs: MavlinkGcsLink) -> np.ndarray:
    slot = gcs.allocator_status.latest()
    return np.full(4, np.nan) if slot is None else np.array(slot.value.delta_hat)


def _wait_estimated(
    gcs: MavlinkGcsLink, truth: np.ndarray, t0: float, timeout_s: float
) -> float | None:
    """Seconds from ``t0`` until every delta_hat is within TOL of ``truth`` (None: not in
    ``timeout_s``)."""
    if not wait_until(lambda: np.all(np.abs(_delta_hat(gcs) - truth) < TOL), timeout_s, 0.05):
        return None
    return time.monotonic() - t0


def test_faults_injected_over_mavlink_and_zenoh_are_estimated_while_holding_position(
    hil: Rig,
) -> None:
    gcs = hil.gcs()
    hil.start_allocator()
    hil.start_sim()
    zgcs = hil.zenoh_gcs()
    assert wait_until(lambda: gcs.odometry.latest() is not None, 20.0), hil.logs()
    assert zgcs.subscribers_matched(timeout_s=20.0), hil.logs()
    assert gcs.set_param(VESSEL_IDS, FAILURE_ENABLE_PARAM, 1) == 1.0
    sim = hil.procs["sim"]
    with setpoints(gcs, hold=np.zeros(3)) as loop:
        time.sleep(3.0)
        healthy = _delta_hat(gcs)
        assert np.all(np.abs(healthy - 1.0) < TOL), healthy
        # Zenoh: thruster 1 (index 0) at half effectiveness
        weak = FaultInjection(0, FaultKind.WEAK, 0.5)
        t0 = time.monotonic()
        for _ in range(10):  # a sample published right after matching may be lost: repeat
            if zgcs.inject_fault(weak) and sim.wait_for("fault injected via zenoh", 1.0):
                break
        t_weak = _wait_estimated(gcs, np.array([0.5, 1.0, 1.0, 1.0]), t0, WEAK_WITHIN_S)
        assert t_weak is not None, (_delta_hat(gcs), hil.logs())
        # MAVLink: thruster 2 (index 1) off
        t0 = time.monotonic()
        assert gcs.inject_failure(FaultKind.OFF, 1) is MavResult.ACCEPTED
        truth = np.array([0.5, 0.0, 1.0, 1.0])
        t_off = _wait_estimated(gcs, truth, t0, OFF_WITHIN_S)
        assert t_off is not None, (_delta_hat(gcs), hil.logs())
        # and the estimates stay there: over 3 s (about 10 estimator samples at the paper's
        # rate), their median within TOL of the truth and every one within 2 TOL. A single
        # sample's noise at this rate reaches TOL (CI: 0.103 once over 3 s, the median well
        # inside); an estimate that drifts away or jumps to another fault fails either bound
        errors = []
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            errors.append(np.abs(_delta_hat(gcs) - truth))
            time.sleep(0.1)
        median = np.median(np.array(errors), axis=0)
        worst = float(np.max(errors))
        assert np.all(median < TOL) and worst < 2 * TOL, (median, worst)
    final = _delta_hat(gcs)
    assert loop.max_position_error_m < HOLD_POSITION_M, loop.max_position_error_m
    assert loop.max_heading_error_rad < HOLD_HEADING_RAD, loop.max_heading_error_rad
    # the sim's own record: the true faults acting at the end are the injected ones
    last = hil.record_rows()[-1]
    assert [float(last[f"delta_T{i}"]) for i in range(1, 5)] == [0.5, 0.0, 1.0, 1.0]
    texts = [s.value.text for s in gcs.drain_statustexts()]
    assert any(t.startswith("thruster 1 fault detected") for t in texts), texts
    assert any(t.startswith("thruster 2 fault detected") for t in texts), texts
    print(
        f"\nWEAK 0.5 on T1 (Zenoh) estimated within {TOL} in {t_weak:.1f} s; OFF on T2 "
        f"(MAVLink) in {t_off:.1f} s; final delta_hat {np.round(final, 3)}; worst error over "
        f"the last 3 s {worst:.3f}; max position error {loop.max_position_error_m * 1e3:.2f} mm, "
        f"heading {loop.max_heading_error_rad:.4f} rad"
    )
