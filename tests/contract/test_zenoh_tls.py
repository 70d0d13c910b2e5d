"""The shipped TLS configs (allocator-tls, vessel-tls, gcs-tls) on loopback, with
certificates made in the test by openssl: mutual TLS, and access control by certificate
common name.

Allowed: the ground station's setpoints, fault injections, status and state query; the
vessel's odometry and the fault injections it receives. Refused: a plain tcp client (there
is no tcp listener), a TLS client without a certificate, one whose certificate another CA
signed, and, once connected, anything a certificate of an unknown name or of the wrong role
tries (the vessel's certificate cannot send setpoints; an "intruder" certificate of our own
CA can neither send nor watch).
"""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

from bridges.zenoh_io.codec import ZenohKeys, encode_wrench_setpoint
from bridges.zenoh_io.config import shipped_config_path
from bridges.zenoh_io.link import (
    ZenohAllocatorLink,
    ZenohGcsLink,
    ZenohLinkError,
    ZenohVesselLink,
    load_config,
    make_config,
)
from ftcap_hil.core.messages import FaultInjection, FaultKind, Odometry, WrenchSetpoint
from ftcap_hil.core.status import AllocatorStatus
from ftcap_hil.runtime.processes import wait_until

pytestmark = [
    pytest.mark.timeout(180),
    pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command"),
]

VESSEL = "tls1"
KEYS = ZenohKeys.for_vessel(VESSEL)
EXT = (
    "basicConstraints=CA:FALSE\nkeyUsage=critical,digitalSignature\n"
    "extendedKeyUsage=serverAuth,clientAuth\nsubjectAltName=IP:127.0.0.1,DNS:localhost\n"
)


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=60)


def _ca(d: Path, name: str) -> None:
    _openssl("genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256",
             "-out", f"{name}-key.pem", cwd=d)  # fmt: skip
    _openssl("req", "-x509", "-new", "-key", f"{name}-key.pem", "-sha256", "-days", "2",
             "-subj", f"/CN={name}", "-out", f"{name}.pem",
             "-addext", "basicConstraints=critical,CA:TRUE",
             "-addext", "keyUsage=critical,keyCertSign,cRLSign", cwd=d)  # fmt: skip


def _leaf(d: Path, file: str, cn: str, ca: str) -> None:
    _openssl("genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256",
             "-out", f"{file}-key.pem", cwd=d)  # fmt: skip
    _openssl("req", "-new", "-key", f"{file}-key.pem", "-subj", f"/CN={cn}",
             "-out", f"{file}.csr", cwd=d)  # fmt: skip
    (d / f"{file}.ext").write_text(EXT)
    _openssl("x509", "-req", "-in", f"{file}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}-key.pem",
             "-CAcreateserial", "-days", "2", "-sha256", "-extfile", f"{file}.ext",
             "-out", f"{file}.pem", cwd=d)  # fmt: skip


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("tls")
    _ca(d, "ca")
    _ca(d, "rogue-ca")
    for file, cn in (("allocator", "ftcap-allocator"), ("gcs", "ftcap-gcs"),
                     ("vessel", "ftcap-vessel"), ("intruder", "intruder")):  # fmt: skip
        _leaf(d, file, cn, "ca")
    _leaf(d, "rogue-gcs", "ftcap-gcs", "rogue-ca")
    return d


@pytest.fixture
def port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _client_conf(certs: Path, port: int, cert: str | None, role: str = "gcs") -> zenoh.Config:
    tls = "transport/link/tls"
    overrides = [
        f"connect/endpoints:{json.dumps([f'tls/127.0.0.1:{port}'])}",
        "connect/timeout_ms:2500",
        f'{tls}/root_ca_certificate:"{certs / "ca.pem"}"',
    ]
    if cert is not None:
        overrides += [
            f'{tls}/connect_certificate:"{certs / f"{cert}.pem"}"',
            f'{tls}/connect_private_key:"{certs / f"{cert}-key.pem"}"',
        ]
    conf = load_config(shipped_config_path(f"{role}-tls"), overrides)
    if cert is None:  # no certificate at all: remove the shipped file names
        conf.insert_json5(f"{tls}/connect_certificate", "null")
        conf.insert_json5(f"{tls}/connect_private_key", "null")
    return conf


@pytest.fixture
def allocator(certs: Path, port: int) -> Iterator[ZenohAllocatorLink]:
    tls = "transport/link/tls"
    conf = load_config(
        shipped_config_path("allocator-tls"),
        [
            f"listen/endpoints:{json.dumps([f'tls/127.0.0.1:{port}'])}",
            f'{tls}/root_ca_certificate:"{certs / "ca.pem"}"',
            f'{tls}/listen_certificate:"{certs / "allocator.pem"}"',
            f'{tls}/listen_private_key:"{certs / "allocator-key.pem"}"',
        ],
    )
    with ZenohAllocatorLink(VESSEL, conf) as link:
        yield link


def _wait_for(cond: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    return wait_until(cond, timeout_s, 0.02)


def _status() -> AllocatorStatus:
    return AllocatorStatus(
        cycle=3, delta_hat=(1.0, 0.5), f_hat=(0.0, 0.0), bf_hat=(0.0, 0.0, 0.0), u=(1.0, 2.0),
        unallocated=(0.0, 0.0, 0.0), saturated=(False, False),
    )  # fmt: skip


def test_authorized_roles_work_over_mutual_tls(
    certs: Path, port: int, allocator: ZenohAllocatorLink
) -> None:
    with (
        ZenohGcsLink(VESSEL, _client_conf(certs, port, "gcs")) as gcs,
        ZenohVesselLink(
            VESSEL, _client_conf(certs, port, "vessel", "vessel"), n_thrusters=2
        ) as vessel,
    ):
        assert gcs.subscribers_matched(KEYS.setpoint_wrench, timeout_s=10.0)
        tau = np.array([5.0, -1.0, 0.5])
        assert _wait_for(
            lambda: (
                gcs.publish_setpoint(WrenchSetpoint(tau))
                and (s := allocator.setpoints.latest()) is not None
                and s.value.tau.tolist() == tau.tolist()
            )
        )
        odom = Odometry(np.array([1.0, 2.0, 0.1]), np.zeros(3), 4.0)
        assert _wait_for(
            lambda: (
                vessel.publish_odometry(odom)
                and allocator.odometry.latest() is not None
                and gcs.odometry.latest() is not None
            )
        )
        fault = FaultInjection(1, FaultKind.WEAK, 0.5)
        assert _wait_for(lambda: gcs.inject_fault(fault) and vessel.faults.received > 0)
        assert _wait_for(
            lambda: allocator.publish_status(_status()) and gcs.status.latest() is not None
        )
        state = gcs.query_state(timeout_s=5.0)
        assert state is not None and state.cycle == 3


@pytest.mark.parametrize("case", ["plain tcp", "no certificate", "another CA"])
def test_unauthenticated_clients_cannot_connect(
    certs: Path, port: int, allocator: ZenohAllocatorLink, case: str
) -> None:
    if case == "plain tcp":
        conf = make_config("client", port, overrides=["connect/timeout_ms:2500"])
    else:
        conf = _client_conf(certs, port, None if case == "no certificate" else "rogue-gcs")
    with pytest.raises(ZenohLinkError):
        ZenohGcsLink(VESSEL, conf).shutdown()
    assert allocator.setpoints.received == 0


def _raw_session(certs: Path, port: int, cert: str) -> zenoh.Session:
    return zenoh.open(_client_conf(certs, port, cert))


def test_access_control_refuses_wrong_roles_and_unknown_names(
    certs: Path, port: int, allocator: ZenohAllocatorLink
) -> None:
    payload = encode_wrench_setpoint(WrenchSetpoint(np.array([999.0, 0.0, 0.0])))
    heard: list[bytes] = []
    with (
        _raw_session(certs, port, "vessel") as wrong_role,
        _raw_session(certs, port, "intruder") as intruder,
    ):
        intruder.declare_subscriber(KEYS.status, lambda s: heard.append(s.payload.to_bytes()))
        time.sleep(1.0)  # declarations settle
        for _ in range(20):
            wrong_role.put(KEYS.setpoint_wrench, payload)
            intruder.put(KEYS.setpoint_wrench, payload)
            intruder.put(KEYS.odometry, b'{"v":1}')
            allocator.publish_status(_status())
            time.sleep(0.05)
        assert allocator.setpoints.received == 0 and allocator.setpoints.malformed == 0
        # An authorized ground station gets through at the same time, so the denial is
        # the ACL's and not a dead link.
        with ZenohGcsLink(VESSEL, _client_conf(certs, port, "gcs")) as gcs:
            assert _wait_for(
                lambda: (
                    gcs.publish_setpoint(WrenchSetpoint(np.array([1.0, 0.0, 0.0])))
                    and allocator.setpoints.received > 0
                )
            )
            assert _wait_for(
                lambda: allocator.publish_status(_status()) and gcs.status.latest() is not None
            )
    latest = allocator.setpoints.latest()
    assert latest is not None and latest.value.tau.tolist() == [1.0, 0.0, 0.0]
    assert allocator.odometry.received == 0 and allocator.odometry.malformed == 0
    assert heard == []
