"""Issue 22, item 1: a steady odometry forger against the real allocator and vessel processes.

While the test asks for a constant surge force, two forgers claim the vessel stands still
where it was when they started, at 100 Hz each: MAVLink ODOMETRY with the vessel's ids
(1/1) from a UDP port of their own, and a Zenoh client putting on the odometry key. Before
the fix the estimator believed them (thrust with no motion: every thruster looks dead) and
took thrusters out. Now the MAVLink forger is refused by address (the allocator accepts
ODOMETRY only from the vessel's inbox) and the plain-Zenoh port, which any local process
may publish on, is used only while the vessel's authenticated MAVLink telemetry is stale.

Asserted: no thruster flagged or taken out during the attack (every delta_hat above 0.8,
its healthy value is 1 +- 0.1; no "fault detected" text), the allocator announces the
second sender, counts the forged datagrams refused, and the ground station keeps getting
its status. Wall-clock figures are printed, not asserted.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from bridges.mavlink.config import VESSEL_IDS
from bridges.mavlink.gcs import MavlinkGcsLink
from bridges.zenoh_io.link import ZenohVesselLink, make_config
from ftcap_hil.core.messages import Odometry
from ftcap_hil.runtime.processes import wait_until
from tests.e2e.rig import Rig, latest_odometry, setpoints
from tests.support.mavlink_peers import DIALECT, RawPeer

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(240)]

ATTACK_S = 30.0
RATE_HZ = 100.0
SURGE = [0.1, 0.0, 0.0]  # N, N, N m: every thruster works, the vessel gets under way
HEALTHY_MIN = 0.8  # healthy delta_hat is 1 +- 0.1 here; a removal takes it to 0


def _delta_hat(gcs: MavlinkGcsLink) -> np.ndarray:
    slot = gcs.allocator_status.latest()
    return np.full(4, np.nan) if slot is None else np.array(slot.value.delta_hat)


class Forgers:
    """The two forgers on threads of their own: a frozen pose, zero velocity, vessel time
    running on from the vessel's latest sample."""

    def __init__(self, hil: Rig, start: Odometry) -> None:
        self.mav = RawPeer(f"udpout:127.0.0.1:{hil.alloc_port}", VESSEL_IDS)
        self.zenoh = ZenohVesselLink("ftcap1", make_config("client", port=hil.zenoh_port))
        self.start = start
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        t0, k = time.monotonic(), 0
        eta = self.start.eta
        q = [math.cos(eta[2] / 2), 0.0, 0.0, math.sin(eta[2] / 2)]
        nan21 = [math.nan] * 21
        ned, frd = DIALECT.MAV_FRAME_LOCAL_NED, DIALECT.MAV_FRAME_BODY_FRD
        while not self._stop.is_set():
            t = self.start.time_s + (time.monotonic() - t0) + 0.05
            self.mav.mav.odometry_send(
                int(t * 1e6), ned, frd, eta[0], eta[1], 0.0, q,
                0.0, 0.0, 0.0, 0.0, 0.0, 0.0, nan21, nan21,
            )  # fmt: skip
            self.zenoh.publish_odometry(Odometry(eta.copy(), np.zeros(3), t))
            self.sent += 1
            k += 1
            self._stop.wait(max(0.0, t0 + k / RATE_HZ - time.monotonic()))

    def __enter__(self) -> Forgers:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.mav.close()
        self.zenoh.shutdown()


@pytest.mark.parametrize(
    ("vessel_inbox", "outcome"),
    [(True, "the trusted source is used"), (False, "estimation frozen")],
    ids=["mavlink-and-zenoh", "zenoh-only"],
)
def test_a_steady_odometry_forger_takes_no_thruster_out(
    hil: Rig, vessel_inbox: bool, outcome: str
) -> None:
    """With the vessel's inbox configured the allocator uses its MAVLink telemetry; without
    (``relay`` empty: no MAVLink ODOMETRY accepted) only plain Zenoh is left, shared with
    the forger, and estimation freezes while two senders are on it."""
    gcs = hil.gcs()
    relay = f'["127.0.0.1:{hil.vessel_port}"]' if vessel_inbox else "[]"
    # the rig names the vessel's inbox as the telemetry source: no source, no MAVLink ODOMETRY
    sources = [] if vessel_inbox else ["mavlink.telemetry_from=[]"]
    alloc = hil.start_allocator([f"mavlink.relay={relay}", *sources])
    hil.start_sim()
    assert wait_until(lambda: gcs.odometry.latest() is not None, 20.0), hil.logs()
    with setpoints(gcs, tau=SURGE):
        time.sleep(4.0)
        assert np.all(_delta_hat(gcs) > HEALTHY_MIN), (_delta_hat(gcs), hil.logs())
        worst = np.ones(4)
        before = [s.value.text for s in gcs.drain_statustexts()]
        statuses = gcs.allocator_status.received
        with Forgers(hil, latest_odometry(gcs)) as forgers:
            end = time.monotonic() + ATTACK_S
            while time.monotonic() < end:
                worst = np.minimum(worst, _delta_hat(gcs))
                time.sleep(0.1)
        served = gcs.allocator_status.received - statuses
        texts = [s.value.text for s in gcs.drain_statustexts()]
    assert np.all(worst > HEALTHY_MIN), (worst, before, texts, hil.logs())
    assert not [t for t in texts if "fault detected" in t], (before, texts)
    alarm = "two odometry senders on zenoh.odometry"
    assert any(alarm in t and outcome in t for t in texts), texts
    assert served > 0.5 * ATTACK_S / 0.1, served  # status at 10 Hz; half of it, loaded
    refused = alloc.output()
    print(
        f"\n{forgers.sent} forged samples per transport in {ATTACK_S:.0f} s; lowest delta_hat "
        f"{np.round(worst, 3)}; {served} statuses received; alarms: "
        f"{[t for t in texts if 'telemetry' in t]}; allocator log:\n{refused[-3000:]}"
    )
