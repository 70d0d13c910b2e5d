"""Interop: MAVProxy lists and sets the allocator's and the vessel's parameters and injects
failures into the vessel, in the two ways docs/hil.md gives:

* standing in for the ground station on its inbox port (``--master=udp:127.0.0.1:14550``,
  which both links list as a peer), and
* as an extra ground station with one link to the allocator's inbox only
  (``--master=udpout:127.0.0.1:14570``, the line of docs/hil.md, also the Docker one): MAVProxy
  sends on that one link, and the allocator relays what is for the vessel, and back;
  with MAVLink 2 signing too (``signing key PASSPHRASE``).

MAVProxy runs headless (no display, loopback only) with ``--default-modules=param,cmdlong,
misc --no-state`` and commands on stdin. Skipped when MAVProxy is not installed.
"""

from __future__ import annotations

import math
import re
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink
from bridges.mavlink.config import ALLOCATOR_IDS, VESSEL_IDS, MavlinkEndpoint
from bridges.mavlink.params import ParamSpec, ParamType
from bridges.mavlink.vessel import FAILURE_ENABLE_PARAM, MavlinkVesselLink
from ftcap_hil.core.messages import FaultInjection, FaultKind
from ftcap_hil.runtime.processes import Child
from tests.support.mavlink_peers import free_udp_ports, wait_until

MAVPROXY = Path(sys.executable).with_name("mavproxy.py")
pytestmark = [
    pytest.mark.timeout(90),
    pytest.mark.usefixtures("no_leaked_threads"),
    pytest.mark.skipif(not MAVPROXY.exists(), reason="MAVProxy is not installed"),
]


class MavproxySession(Child):
    """MAVProxy as a child process, driven through stdin, its output read line by line;
    :meth:`close` ends it with EOF on its stdin (its clean exit), SIGKILL if that fails."""

    def __init__(
        self, master: str, target: tuple[int, int], cwd: Path, modules: str = "param,cmdlong,misc"
    ) -> None:
        super().__init__(
            "mavproxy",
            [
                sys.executable, str(MAVPROXY), f"--master={master}",
                f"--default-modules={modules}", "--no-state", "--mav20",
                f"--target-system={target[0]}", f"--target-component={target[1]}",
            ],
            stdin_pipe=True, cwd=cwd, env={"HOME": str(cwd)},
        )  # fmt: skip
        self.transcript: list[str] = []

    def command(self, line: str) -> None:
        self.write(line)

    def expect(self, pattern: str, timeout_s: float = 10.0) -> str:
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        while (line := self.next_line(deadline - time.monotonic())) is not None:
            self.transcript.append(line)
            if regex.search(line):
                return line
        raise AssertionError(
            f"MAVProxy never printed {pattern!r}; got:\n" + "\n".join(self.transcript)
        )

    def close(self) -> None:
        self.stop(None, 10.0)
        super().close()


@pytest.fixture
def system(tmp_path) -> Iterator[tuple[MavproxySession, MavlinkAllocatorLink, MavlinkVesselLink]]:
    gcs_port, allocator_port, vessel_port = free_udp_ports(3)
    params = [
        ParamSpec("ALLOC_W_U", 1.0, min=0.0, max=10.0),
        ParamSpec("ALLOC_HORIZON", 4, ParamType.INT, 1, 50),
    ]
    config = AllocatorLinkConfig(n_thrusters=4, max_wrench=(100.0, 50.0, 200.0))
    allocator_ep = MavlinkEndpoint.inbox(allocator_port, ALLOCATOR_IDS, (gcs_port,))
    vessel_ep = MavlinkEndpoint.inbox(vessel_port, VESSEL_IDS, (allocator_port, gcs_port))
    with (
        MavlinkAllocatorLink(config, allocator_ep, params) as allocator,
        MavlinkVesselLink(4, vessel_ep) as vessel,
    ):
        session = MavproxySession(f"udp:127.0.0.1:{gcs_port}", ALLOCATOR_IDS, tmp_path)
        try:
            yield session, allocator, vessel
        finally:
            session.close()
    assert session.proc.returncode is not None


def test_mavproxy_sets_allocator_params_and_injects_a_vessel_failure(system) -> None:
    mavproxy, allocator, vessel = system
    mavproxy.expect(r"Detected vehicle 1:191", timeout_s=30)
    mavproxy.expect(r"Received 2 parameters")  # MAVProxy fetches the table on connect

    mavproxy.command("param set ALLOC_W_U 2.5")
    assert wait_until(lambda: allocator.params.get("ALLOC_W_U") == 2.5)
    mavproxy.command("param set ALLOC_HORIZON 12")
    assert wait_until(lambda: allocator.params.get("ALLOC_HORIZON") == 12)
    # MAVProxy C-casts the integer; the echo it gets is C-cast too (issue 22, item 6: it
    # printed "Failed to set ... (invalid returned value 1.7e-44)" and cached the tiny float)
    mavproxy.command("param show ALLOC_HORIZON")
    mavproxy.expect(r"ALLOC_HORIZON\s+12(\.0*)?\s*$")
    assert not [line for line in mavproxy.transcript if "Failed to set" in line]
    mavproxy.command("param set ALLOC_W_U 50")
    mavproxy.expect(r"ALLOC_W_U not set: 50 outside \[0, 10\]")  # our STATUSTEXT
    mavproxy.command("param show ALLOC*")
    mavproxy.expect(r"ALLOC_W_U\s+2\.5")
    assert allocator.params.values() == {"ALLOC_W_U": 2.5, "ALLOC_HORIZON": 12.0}

    mavproxy.command("set target_component 1")
    mavproxy.command("param fetch")
    mavproxy.expect(r"Received 1 parameters")
    mavproxy.command("long INJECT_FAILURE 101 1 3")
    mavproxy.expect(r"INJECT_FAILURE: DENIED")  # SYS_FAILURE_EN is 0 by default
    mavproxy.command(f"param set {FAILURE_ENABLE_PARAM} 1")
    assert wait_until(lambda: vessel.fault_injection_enabled)
    mavproxy.command("long INJECT_FAILURE 101 1 3")
    mavproxy.expect(r"INJECT_FAILURE: ACCEPTED")
    assert [s.value.index for s in vessel.drain_faults()] == [2]

    mavproxy.command("long INJECT_FAILURE 101 5 0 0.5")  # SLOW on all -> WEAK, delta 0.5
    mavproxy.expect(r"INJECT_FAILURE: ACCEPTED")
    faults = [s.value for s in vessel.drain_faults()]
    assert faults == [FaultInjection(i, FaultKind.WEAK, 0.5) for i in range(4)]


def _through_the_allocator(
    tmp_path: Path, key_file: Path | None = None
) -> Iterator[tuple[MavproxySession, MavlinkAllocatorLink, MavlinkVesselLink]]:
    gcs_port, allocator_port, vessel_port = free_udp_ports(3)  # nobody listens on gcs_port
    key = None if key_file is None else str(key_file)
    config = AllocatorLinkConfig(n_thrusters=4, max_wrench=(100.0, 50.0, 200.0))
    allocator_ep = MavlinkEndpoint(
        f"udpin:127.0.0.1:{allocator_port}", *ALLOCATOR_IDS, (f"127.0.0.1:{gcs_port}",),
        relay=(f"127.0.0.1:{vessel_port}",), key_file=key,
    )  # fmt: skip
    vessel_ep = MavlinkEndpoint(
        f"udpin:127.0.0.1:{vessel_port}", *VESSEL_IDS,
        (f"127.0.0.1:{allocator_port}", f"127.0.0.1:{gcs_port}"), key_file=key,
    )  # fmt: skip
    params = [ParamSpec("ALLOC_HORIZON", 4, ParamType.INT, 1, 50)]
    with (
        MavlinkAllocatorLink(config, allocator_ep, params) as allocator,
        MavlinkVesselLink(4, vessel_ep) as vessel,
    ):
        modules = "param,cmdlong,misc" + (",signing" if key_file else "")
        master = f"udpout:127.0.0.1:{allocator_port}"
        session = MavproxySession(master, ALLOCATOR_IDS, tmp_path, modules)
        try:
            yield session, allocator, vessel
        finally:
            session.close()


@pytest.fixture
def relayed(tmp_path) -> Iterator[tuple[MavproxySession, MavlinkAllocatorLink, MavlinkVesselLink]]:
    yield from _through_the_allocator(tmp_path)


def _drive_both_components(
    mavproxy: MavproxySession, allocator: MavlinkAllocatorLink, vessel: MavlinkVesselLink
) -> None:
    mavproxy.expect(r"Detected vehicle 1:191", timeout_s=30)
    mavproxy.command("param fetch")
    mavproxy.expect(r"Received 1 parameters")
    mavproxy.command("param set ALLOC_HORIZON 12")  # C-cast by MAVProxy, understood
    assert wait_until(lambda: allocator.params.get("ALLOC_HORIZON") == 12)
    mavproxy.command("set target_component 1")  # the vessel, behind the allocator's inbox
    mavproxy.command("param fetch")
    mavproxy.expect(r"Received 1 parameters")
    mavproxy.command(f"param set {FAILURE_ENABLE_PARAM} 1")
    assert wait_until(lambda: vessel.fault_injection_enabled)
    mavproxy.command("long INJECT_FAILURE 101 4 2")  # WRONG on thruster 2, param4 left 0
    mavproxy.expect(r"INJECT_FAILURE: ACCEPTED")
    (fault,) = [s.value for s in vessel.drain_faults()]
    assert (fault.index, fault.kind) == (1, FaultKind.BIAS)
    assert math.isnan(fault.value)  # 0 means the simulator's default bias, not 0 N
    mavproxy.command("long DO_SET_SERVO 1 1500")  # unsupported: acknowledged all the same
    mavproxy.expect(r"DO_SET_SERVO: UNSUPPORTED")


def test_mavproxy_with_one_link_to_the_allocator_reaches_the_vessel_too(relayed) -> None:
    mavproxy, allocator, vessel = relayed
    _drive_both_components(mavproxy, allocator, vessel)
    assert allocator.stats.relayed > 0
    assert len(allocator._port.table.dynamic_peers()) == 1  # noqa: SLF001  (MAVProxy)


def test_mavproxy_signed_through_the_allocator(tmp_path) -> None:
    key_file = tmp_path / "mavlink.key"
    key_file.write_text("ftcap-interop-passphrase\n")
    key_file.chmod(0o600)
    for mavproxy, allocator, vessel in _through_the_allocator(tmp_path, key_file):
        mavproxy.command("signing key ftcap-interop-passphrase")
        _drive_both_components(mavproxy, allocator, vessel)
        assert allocator.stats.bad_signature == vessel.stats.bad_signature == 0
        assert vessel.stats.unsigned == 0  # what the allocator relayed was signed
