"""Start order: the allocator, the vessel and the ground station come up in any order, a
vessel may join late and an allocator may be restarted mid-run; the flight completes and
the records say what happened.

Each case runs the demo's own processes (``ftcap-hil can-hub``, ``allocator``, ``sim`` and
``gcs`` with the demo's command lines, ``ftcap_hil.apps.demo``) on free loopback ports and
flies example 1's first fault: the start orders and the late vessel a 6 s mission with its
onset at 3 s (missions/start-order-brief.toml), the restart the demo's compressed example
1 for 15 s (onset at 12 s, after the new allocator is up); each onset is a WEAK and a BIAS
injection that must be acknowledged. Judged on what the ground station recorded and logged
(exit code, mission time covered, injections), never on wall-clock counts.
"""

from __future__ import annotations

import itertools
import json
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from ftcap_hil.apps.demo import Ports, allocator_argv, gcs_argv, vessel_argv
from ftcap_hil.runtime.processes import Child, Supervisor, start_can_hub, wait_until
from tests.support.records import float_rows

pytestmark = pytest.mark.e2e

BRIEF = str(Path(__file__).parent / "missions" / "start-order-brief.toml")
BRIEF_S = 6.0
MISSION = "paper-4.2-ex1-short"
FLIGHT_S = 15.0
PERIOD_S = 0.2827
GAP_S = 2.0  # between two starts: each process is well into its start-up when the next comes
FLIGHT_TIMEOUT_S = 120.0  # connect (up to 20 s) + 15 s flown + write-up, on a loaded machine


class Rig:
    """The CAN hub up, the three processes' command lines ready; started by :meth:`start`."""

    def __init__(self, out: Path, mission: str = BRIEF, flight_s: float = BRIEF_S) -> None:
        self.out = out
        (out / "logs").mkdir(parents=True, exist_ok=True)
        self.sup = Supervisor(out / "logs", grace_s=8.0)
        _, channel = start_can_hub(self.sup.start, timeout_s=30.0)
        picked = Ports.pick()
        self.ports = Ports(picked.gcs, picked.allocator, picked.vessel, picked.zenoh,
                           int(channel.rsplit(":", 1)[1]))  # fmt: skip
        self.argv = {
            "allocator": allocator_argv(self.ports),
            "vessel": vessel_argv(self.ports),
            "gcs": gcs_argv(self.ports, mission, out / "flight", flight_s, plots=False),
        }

    def start(self, name: str) -> Child:
        return self.sup.start(name, self.argv[name])

    def log(self, name: str) -> str:
        return (self.out / "logs" / f"{name}.log").read_text(errors="replace")

    def fly_to_the_end(self, gcs: Child) -> dict:
        """The ground station's exit (0 required) and its results.json."""
        code = gcs.wait(FLIGHT_TIMEOUT_S)
        logs = {c.name: c.output()[-1500:] for c in self.sup.children}
        assert code == 0, logs
        return json.loads((self.out / "flight" / "results.json").read_text())


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Rig]:
    r = Rig(tmp_path)
    try:
        yield r
    finally:
        r.sup.stop_all()


@pytest.fixture
def long_rig(tmp_path: Path) -> Iterator[Rig]:
    """The demo's compressed example 1, flown for 15 s."""
    r = Rig(tmp_path, MISSION, FLIGHT_S)
    try:
        yield r
    finally:
        r.sup.stop_all()


def _flown(results: dict) -> None:
    """Both injections of the first onset acknowledged."""
    mode = results["modes"]["ftcap"]
    injections = [(i["kind"], i["thruster"], i["result"]) for i in mode["injections"]]
    assert injections == [("WEAK", 1, "ACCEPTED"), ("BIAS", 1, "ACCEPTED")], injections


def _rows(out: Path) -> list[dict[str, float]]:
    return float_rows(out / "flight" / "ftcap" / "timeseries.csv")


@pytest.mark.timeout(240)
@pytest.mark.parametrize(
    "order", list(itertools.permutations(("allocator", "vessel", "gcs"))), ids="-".join
)
def test_any_start_order_flies_the_mission(rig: Rig, order: tuple[str, str, str]) -> None:
    for name in order:
        child = rig.start(name)
        time.sleep(GAP_S)
        assert child.running(), rig.log(name)[-2000:]
    gcs = rig.sup.by_name()["gcs"]
    _flown(rig.fly_to_the_end(gcs))
    rows = _rows(rig.out)
    assert rows[-1]["t"] > BRIEF_S - 2 * PERIOD_S and len(rows) > 0.9 * BRIEF_S / PERIOD_S


@pytest.mark.timeout(240)
def test_a_vessel_started_10_s_late_joins_the_flight(rig: Rig) -> None:
    """Allocator and ground station first; the vessel 10 s later (within the ground
    station's 20 s connect timeout): the flight starts when the vessel's odometry comes,
    and the allocator says it waited for the vessel's telemetry."""
    rig.start("allocator")
    gcs = rig.start("gcs")
    time.sleep(10.0)
    assert gcs.running(), rig.log("gcs")[-2000:]
    rig.start("vessel")
    _flown(rig.fly_to_the_end(gcs))
    assert len(_rows(rig.out)) > 0.9 * BRIEF_S / PERIOD_S
    log = rig.log("allocator")
    assert "telemetry stale: estimation frozen" in log, log[-3000:]
    assert "telemetry recovered" in log, log[-3000:]


@pytest.mark.timeout(300)
def test_an_allocator_restarted_mid_flight_takes_over_and_the_record_says_so(
    long_rig: Rig,
) -> None:
    """The allocator is stopped (SIGTERM) 4 s into the flight and a new one started 2 s
    later on the same ports: the ground station flies on (it needs only the vessel's
    odometry) and logs the allocator's silence and its end; the injections at 12 s are
    acknowledged by the vessel."""
    first = long_rig.start("allocator")
    long_rig.start("vessel")
    gcs = long_rig.start("gcs")
    assert wait_until(lambda: "flying" in long_rig.log("gcs"), 60.0), long_rig.log("gcs")[-2000:]
    time.sleep(4.0)
    long_rig.sup.stop(first, signal.SIGTERM)
    assert first.returncode == 0, long_rig.log("allocator")[-2000:]  # a clean stop
    time.sleep(2.0)
    long_rig.sup.start("allocator", long_rig.argv["allocator"])
    _flown(long_rig.fly_to_the_end(gcs))
    log = long_rig.log("gcs")
    assert "no FTCAP_STATUS from the allocator" in log, log[-3000:]
    assert "over: no FTCAP_STATUS from the allocator" in log, log[-3000:]
    assert len(_rows(long_rig.out)) > 0.9 * FLIGHT_S / PERIOD_S
