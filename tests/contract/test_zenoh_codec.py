"""The Zenoh payload encoding: literal payloads, round trips, and what the decoders refuse."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from bridges.zenoh_io.codec import (
    MAX_PAYLOAD_BYTES,
    ZenohKeys,
    decode_fault_injection,
    decode_odometry,
    decode_status,
    decode_thruster_command,
    decode_wrench_setpoint,
    encode_fault_injection,
    encode_odometry,
    encode_status,
    encode_thruster_command,
    encode_wrench_setpoint,
)
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import (
    FaultInjection,
    FaultKind,
    Odometry,
    ThrusterCommand,
    WrenchSetpoint,
)
from ftcap_hil.core.status import AllocatorStatus, Mode


def status_four_thrusters(**changes: object) -> AllocatorStatus:
    values: dict[str, object] = dict(
        mode=Mode.FTCAP,
        cycle=1200,
        overruns=3,
        degraded=False,
        delta_hat=(1.0, 0.98, 0.0, 1.0),
        f_hat=(0.0, 0.0, 12.5, 0.0),
        bf_hat=(12.5, 0.0, -3.0),
        u=(100.0, -50.0, 0.0, 25.0),
        tau_demand=(1.0, 2.0, 3.0),
        unallocated=(0.0, 1.5, 0.0),
        saturated=(False, True, False, False),
        faulty=(False, False, True, False),
        delta_std=(0.01, 0.02, 0.05, 0.01),
        observable=(True, True, False, True),
        setpoint_age_s=0.012,
        telemetry_stale=True,
        esc_rpm=(100.0, math.nan, 0.0, -50.0),
        esc_current_a=(0.5, math.nan, 0.1, 0.2),
        esc_age_s=(0.01, math.inf, 0.02, 0.03),
        hypothesis=("healthy", "healthy", "jammed", "telemetry-lost"),
    )
    values.update(changes)
    return AllocatorStatus.checked(**values)


def test_keys_of_a_vessel() -> None:
    keys = ZenohKeys.for_vessel("cybership2")
    assert keys.setpoint_wrench == "ftcap/cybership2/setpoint/wrench"
    assert keys.odometry == "ftcap/cybership2/telemetry/odometry"
    assert keys.thruster_command == "ftcap/cybership2/thrusters/command"
    assert keys.status == "ftcap/cybership2/allocator/status"
    assert keys.state == "ftcap/cybership2/allocator/state"
    assert keys.fault_inject == "ftcap/cybership2/fault/inject"


@pytest.mark.parametrize("name", ["", "a/b", "ship*", "**", "my ship", "$x"])
def test_vessel_name_must_be_one_plain_key_chunk(name: str) -> None:
    with pytest.raises(ValueError, match="vessel name"):
        ZenohKeys.for_vessel(name)


def test_documented_setpoint_payload_decodes() -> None:
    msg = decode_wrench_setpoint(b'{"v":1,"X_N":1200.0,"Y_N":0.0,"N_Nm":-350.0}')
    np.testing.assert_array_equal(msg.tau, [1200.0, 0.0, -350.0])


def test_setpoint_encodes_to_named_si_fields() -> None:
    payload = encode_wrench_setpoint(WrenchSetpoint.checked([10, -2.5, 3]))
    assert json.loads(payload) == {"v": 1, "X_N": 10.0, "Y_N": -2.5, "N_Nm": 3.0}


def test_odometry_round_trip_and_unknown_time_is_null() -> None:
    odom = Odometry.checked([10.0, -4.0, 0.5], [1.2, 0.1, -0.02], time_s=42.5)
    back = decode_odometry(encode_odometry(odom))
    np.testing.assert_array_equal(back.eta, odom.eta)
    np.testing.assert_array_equal(back.nu, odom.nu)
    assert back.time_s == 42.5
    untimed = encode_odometry(Odometry.checked([0, 0, 0], [0, 0, 0]))
    assert json.loads(untimed)["time_s"] is None
    assert math.isnan(decode_odometry(untimed).time_s)


def test_thruster_command_round_trip_and_length_check() -> None:
    payload = encode_thruster_command(ThrusterCommand.checked([1.0, -2.0, 3.5]))
    assert json.loads(payload) == {"v": 1, "u_N": [1.0, -2.0, 3.5]}
    np.testing.assert_array_equal(decode_thruster_command(payload, m=3).u, [1.0, -2.0, 3.5])
    with pytest.raises(MalformedMessage, match="u_N"):
        decode_thruster_command(payload, m=4)


@pytest.mark.parametrize(
    "fault",
    [
        FaultInjection(0, FaultKind.OFF),
        FaultInjection(3, FaultKind.WEAK, 0.4),
        FaultInjection(1, FaultKind.BIAS, -20.0),
        FaultInjection(2, FaultKind.STUCK),
        FaultInjection(2, FaultKind.OK),
    ],
)
def test_fault_injection_round_trip(fault: FaultInjection) -> None:
    back = decode_fault_injection(encode_fault_injection(fault), m=4)
    assert (back.index, back.kind) == (fault.index, fault.kind)
    assert back.value == fault.value or (math.isnan(back.value) and math.isnan(fault.value))


def test_status_round_trip_keeps_every_field() -> None:
    status = status_four_thrusters()
    back = decode_status(encode_status(status))
    for f in dataclasses.fields(AllocatorStatus):
        want, got = getattr(status, f.name), getattr(back, f.name)
        if f.name in ("esc_rpm", "esc_current_a"):
            np.testing.assert_array_equal(got, want, err_msg=f.name)  # NaN == NaN here
        else:
            assert got == want, f.name


def test_status_payload_names_wrenches_and_nulls_infinite_ages() -> None:
    obj = json.loads(encode_status(status_four_thrusters(mode=Mode.CAP)))
    assert obj["mode"] == "cap"
    assert obj["bf_hat"] == {"X_N": 12.5, "Y_N": 0.0, "N_Nm": -3.0}
    assert obj["port_age_s"] == {
        "setpoint": 0.012, "telemetry": None, "esc1": 0.01, "esc2": None, "esc3": 0.02,
        "esc4": 0.03,
    }  # fmt: skip
    assert obj["f_hat_N"] == [0.0, 0.0, 12.5, 0.0]
    assert obj["esc_rpm"] == [100.0, None, 0.0, -50.0]


def test_a_v1_status_without_the_later_fields_decodes() -> None:
    obj = json.loads(encode_status(status_four_thrusters()))
    for key in ("tau_demand", "faulty", "esc_failed", "probing", "malformed", "esc_rpm",
                "esc_current_A", "estimation_frozen", "delta_std", "observable"):  # fmt: skip
        del obj[key]
    back = decode_status(json.dumps(obj).encode())
    assert back.faulty == () and back.tau_demand == () and back.malformed == 0
    assert back.delta_hat == (1.0, 0.98, 0.0, 1.0)


@pytest.mark.parametrize(
    "changes",
    [
        {"u": (0.0,) * 3},
        {"saturated": (False,) * 5},
        {"faulty": (False,) * 3},
        {"delta_hat": (1.0, math.nan, 1.0, 1.0)},
        {"bf_hat": (0.0,) * 2},
        {"esc_rpm": (1.0,)},
    ],
)
def test_an_inconsistent_status_cannot_be_built(changes: dict[str, object]) -> None:
    with pytest.raises(MalformedMessage):
        status_four_thrusters(**changes)


def test_a_delta_std_json_cannot_carry_is_refused() -> None:
    with pytest.raises(MalformedMessage):
        encode_status(status_four_thrusters(delta_std=(0.01, math.nan, 0.05, 0.01)))


def test_encoders_refuse_non_finite_values() -> None:
    with pytest.raises(MalformedMessage):
        encode_wrench_setpoint(WrenchSetpoint(np.array([1.0, math.nan, 0.0])))
    with pytest.raises(MalformedMessage):
        encode_thruster_command(ThrusterCommand(np.array([math.inf])))
    with pytest.raises(MalformedMessage):
        encode_fault_injection(FaultInjection(0, FaultKind.BIAS, math.inf))


BAD_SETPOINTS = [
    b"",
    b"\xff\xfe",
    b"garbage",
    b"[1, 2, 3]",
    b'{"X_N":1,"Y_N":2,"N_Nm":3}',  # no version
    b'{"v":2,"X_N":1,"Y_N":2,"N_Nm":3}',
    b'{"v":true,"X_N":1,"Y_N":2,"N_Nm":3}',
    b'{"v":1,"X_N":1,"Y_N":2}',
    b'{"v":1,"X_N":NaN,"Y_N":2,"N_Nm":3}',
    b'{"v":1,"X_N":Infinity,"Y_N":2,"N_Nm":3}',
    b'{"v":1,"X_N":1e999,"Y_N":2,"N_Nm":3}',
    b'{"v":1,"X_N":"1","Y_N":2,"N_Nm":3}',
    b'{"v":1,"X_N":true,"Y_N":2,"N_Nm":3}',
    b'{"v":1,"X_N":null,"Y_N":2,"N_Nm":3}',
    b'{"v":1,"X_N":[1],"Y_N":2,"N_Nm":3}',
]


@pytest.mark.parametrize("payload", BAD_SETPOINTS)
def test_setpoint_decoder_refuses(payload: bytes) -> None:
    with pytest.raises(MalformedMessage):
        decode_wrench_setpoint(payload)


def test_decoders_refuse_oversized_payloads() -> None:
    with pytest.raises(MalformedMessage, match="bytes"):
        decode_thruster_command(b" " * (MAX_PAYLOAD_BYTES + 1))


@pytest.mark.parametrize(
    "payload",
    [
        b'{"v":1,"u_N":[]}',
        b'{"v":1,"u_N":[1,2,"3"]}',
        b'{"v":1,"u_N":[1,true]}',
        b'{"v":1,"u_N":[1,[2]]}',
        b'{"v":1,"u_N":[1,1e999]}',
        b'{"v":1,"u_N":7}',
    ],
)
def test_thruster_command_decoder_refuses(payload: bytes) -> None:
    with pytest.raises(MalformedMessage, match="u_N"):
        decode_thruster_command(payload)


@pytest.mark.parametrize(
    "payload",
    [
        b'{"v":1,"index":0,"kind":"explode"}',
        b'{"v":1,"index":-1,"kind":"off"}',
        b'{"v":1,"index":1.0,"kind":"off"}',
        b'{"v":1,"index":true,"kind":"off"}',
        b'{"v":1,"index":9,"kind":"off"}',  # m = 4
        b'{"v":1,"index":0,"kind":"weak","value":1.5}',
        b'{"v":1,"index":0,"kind":"bias","value":"10"}',
        b'{"v":1,"kind":"off"}',
    ],
)
def test_fault_decoder_refuses(payload: bytes) -> None:
    with pytest.raises(MalformedMessage):
        decode_fault_injection(payload, m=4)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("u_N", [1.0, 2.0]),
        ("saturated", [0, 1, 0, 0]),
        ("degraded", "no"),
        ("cycle", -1),
        ("port_age_s", {"setpoint": -0.5}),
        ("stale", {"setpoint": 1}),
        ("bf_hat", [0.0, 0.0, 0.0]),
        ("mode", 3),
        ("mode", "normal"),
        ("faulty", [True]),
    ],
)
def test_status_decoder_refuses(field: str, value: object) -> None:
    obj = json.loads(encode_status(status_four_thrusters()))
    obj[field] = value
    with pytest.raises(MalformedMessage, match=field):
        decode_status(json.dumps(obj).encode())


def test_pure_modules_do_not_import_zenoh() -> None:
    code = (
        "import sys, bridges.zenoh_io.codec, bridges.zenoh_io.config;"
        " sys.exit('zenoh' in sys.modules)"
    )
    assert subprocess.run([sys.executable, "-c", code], timeout=60).returncode == 0


@pytest.mark.parametrize(
    "literal", ["9" * 19, "-" + "9" * 400, "9" * 5000, "1" + "0" * 400 + ".0", "1e999"]
)
def test_huge_number_literals_are_malformed_not_exceptions(literal: str) -> None:
    payloads = [
        f'{{"v":1,"X_N":{literal},"Y_N":0,"N_Nm":0}}',
        f'{{"v":1,"u_N":[{literal}]}}',
        f'{{"v":1,"index":{literal},"kind":"off"}}',
        f'{{"v":1,"index":0,"kind":"bias","value":{literal}}}',
        f'{{"v":{literal}}}',
    ]
    decoders = [decode_wrench_setpoint, decode_thruster_command, decode_fault_injection]
    for payload in payloads:
        for decode in (*decoders, decode_odometry, decode_status):
            with pytest.raises(MalformedMessage):
                decode(payload.encode())


def test_wrench_limit_drops_setpoints_beyond_it() -> None:
    ok = b'{"v":1,"X_N":100.0,"Y_N":-100.0,"N_Nm":5.0}'
    assert decode_wrench_setpoint(ok, limit=(100.0, 100.0, 5.0)).tau.tolist() == [100, -100, 5]
    with pytest.raises(MalformedMessage, match="beyond the limit"):
        decode_wrench_setpoint(ok, limit=(100.0, 99.0, 5.0))
    assert decode_wrench_setpoint(ok).tau[0] == 100.0  # no limit: as before
