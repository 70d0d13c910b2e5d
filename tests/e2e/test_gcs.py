"""End-to-end: ``ftcap-hil gcs`` and ``ftcap-hil demo`` fail fast and clearly when there is
nothing to talk to or nothing to fly."""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path

import pytest

from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink
from bridges.mavlink.config import ALLOCATOR_IDS, VESSEL_IDS, MavlinkEndpoint
from bridges.mavlink.vessel import MavlinkVesselLink
from tests.e2e.demo_support import free_udp_ports, ftcap_hil, start, stderr_of

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(60)]


def _fly(
    out: Path, ports: Sequence[int], connect_timeout_s: float
) -> subprocess.CompletedProcess[bytes]:
    """``ftcap-hil gcs`` flying paper-4.2-ex1 with (gcs, allocator, vessel) UDP ports."""
    gcs, allocator, vessel = ports
    return subprocess.run(
        ftcap_hil(
            "gcs", "--mission", "paper-4.2-ex1", "--out", str(out),
            "--gcs-port", str(gcs), "--allocator-port", str(allocator),
            "--vessel-port", str(vessel), "--set", f"gcs.connect_timeout_s={connect_timeout_s:g}",
        ),
        capture_output=True,
        timeout=30,
    )  # fmt: skip


def test_gcs_gives_up_when_no_vessel_answers(tmp_path: Path) -> None:
    ports = free_udp_ports(3)
    started = time.monotonic()
    proc = _fly(tmp_path / "out", ports, connect_timeout_s=1.5)
    assert proc.returncode == 3
    assert b"no HEARTBEAT from the vessel" in proc.stderr
    assert time.monotonic() - started < 20.0
    assert not (tmp_path / "out" / "results.json").exists()


def test_gcs_does_not_fly_while_the_allocator_is_still_booting(tmp_path: Path) -> None:
    # Both links heartbeat, but the allocator's says BOOT (its loop never ran a cycle): the
    # mission must not start against a link whose control loop is not running.
    gcs, allocator, vessel = free_udp_ports(3)
    config = AllocatorLinkConfig(n_thrusters=4, max_wrench=(0.3, 0.3, 0.06))
    with (
        MavlinkAllocatorLink(config, MavlinkEndpoint.inbox(allocator, ALLOCATOR_IDS, (gcs,))),
        MavlinkVesselLink(4, MavlinkEndpoint.inbox(vessel, VESSEL_IDS, (gcs,))),
    ):
        proc = _fly(tmp_path / "out", (gcs, allocator, vessel), connect_timeout_s=4.0)
    assert proc.returncode == 3, proc.stderr
    assert b"still reports MAV_STATE_BOOT" in proc.stderr, proc.stderr
    assert not (tmp_path / "out" / "results.json").exists()


def test_gcs_interrupted_while_waiting_for_its_peers_exits_130(tmp_path: Path) -> None:
    # SIGINT during the start-up (nobody answers, the connect timeout is long): the shared
    # exit code of an interrupted command, at once, and nothing written
    gcs, allocator, vessel = free_udp_ports(3)
    argv = ftcap_hil(
        "gcs", "--mission", "paper-4.2-ex1", "--out", str(tmp_path / "out"),
        "--gcs-port", str(gcs), "--allocator-port", str(allocator),
        "--vessel-port", str(vessel), "--set", "gcs.connect_timeout_s=60",
    )  # fmt: skip
    with start("gcs", argv, tmp_path) as proc:
        time.sleep(4.0)  # past the imports: waiting for a HEARTBEAT
        started = time.monotonic()
        proc.send(signal.SIGINT)
        code = proc.wait(20)
    stderr = stderr_of(proc)
    assert code == 130, stderr
    assert "interrupted" in stderr, stderr
    assert time.monotonic() - started < 10.0
    assert not (tmp_path / "out" / "results.json").exists()


def test_gcs_refuses_a_bad_mission_value_naming_the_key(tmp_path: Path) -> None:
    proc = subprocess.run(
        ftcap_hil("gcs", "--mission", "paper-4.2-ex1", "--set", "mission.mode=turbo"),
        capture_output=True,
        timeout=30,
    )
    assert proc.returncode == 2
    assert b"paper-4.2-ex1.toml: [mission] mode: 'turbo' is not one of" in proc.stderr


def test_demo_refuses_an_unknown_mission_before_starting_anything(tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = subprocess.run(
        ftcap_hil("demo", "--mission", "no-such-mission", "--out", str(out)),
        capture_output=True,
        timeout=30,
    )
    assert proc.returncode == 2
    assert b"no-such-mission" in proc.stderr
    assert not (out / "logs" / "pids.json").exists()
