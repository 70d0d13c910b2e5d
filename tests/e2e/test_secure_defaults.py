"""End-to-end: the allocator daemon and the simulated vessel refuse, at start and before any
port is opened, a MAVLink or Zenoh link that reaches beyond this machine's loopback without
authentication (issue 33): exit 2, the file, the table and the setting in the message.

The addresses are TEST-NET ones (RFC 5737): nothing is bound or sent there, the processes
stop while reading their configuration. The opt-out (``allow_unauthenticated``) and the
signed case are judged by the configuration readers (tests/unit/test_config_files.py):
started, they would send to those addresses."""

from __future__ import annotations

import subprocess

import pytest

from tests.e2e.demo_support import ftcap_hil

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(120)]

CASES = [
    (
        ["--set", 'mavlink.peers=["192.0.2.8:14550"]'],
        "[mavlink] key_file: unset, and peers contains '192.0.2.8:14550' reaches beyond "
        "loopback",
    ),
    (
        ["--set", "mavlink.connection=udpin:0.0.0.0:14999", "--set",
         "mavlink.bind_all_interfaces=true"],
        "[mavlink] key_file: unset, and connection = 'udpin:0.0.0.0:14999' reaches beyond",
    ),
    (
        ["--set", "mavlink.enabled=false", "--set", 'zenoh.connect="tcp/192.0.2.9:7447"'],
        "connect/endpoints contains 'tcp/192.0.2.9:7447', beyond loopback without mutual "
        "TLS and access control",
    ),
]  # fmt: skip


@pytest.mark.parametrize(("command", "config"), [("allocator", "allocator.toml"),
                                                 ("sim", "vessel.toml")])  # fmt: skip
@pytest.mark.parametrize(("sets", "message"), CASES)
def test_an_unauthenticated_link_beyond_loopback_stops_the_start(
    command: str, config: str, sets: list[str], message: str
) -> None:
    # an unreachable CAN hub: had the configuration passed, the start would fail there (1)
    argv = ftcap_hil(command, "--set", "can.channel=127.0.0.1:9", *sets)
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert f"{config}: " in proc.stderr and message in proc.stderr, proc.stderr[-2000:]
    assert "allow_unauthenticated = true" in proc.stderr
