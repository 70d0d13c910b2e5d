"""DroneCAN codec and force <-> raw map, checked against an independent reference encoder.

The reference below packs int14 arrays and computes the transfer CRC from the UAVCAN v0
specification (CRC-16-CCITT-FALSE over the 64-bit data type signature, then the payload)
without the dronecan package, so an encoding bug shared by codec and decoder would show.
"""

from __future__ import annotations

import math

import dronecan
import numpy as np
import pytest
from dronecan.transport import Frame, Transfer, TransferManager

from bridges.can_io.assembler import TransferAssembler
from bridges.can_io.codec import (
    PRIORITY_HIGH,
    CanFrame,
    DataType,
    EscStatusMsg,
    Health,
    Mode,
    NodeStatusMsg,
    RawCommandMsg,
    TransferIds,
    decode_frames,
    encode,
    encode_raw_command,
    with_transfer_id,
)
from bridges.can_io.force_map import RAW_MAX, ForceRawMap, NonFiniteCommand
from ftcap_hil.core.errors import MalformedMessage

RAW_COMMAND_SIGNATURE = 0x217F5C87D7EC951D  # uavcan.equipment.esc.RawCommand, per DSDL


def _crc16_ccitt(data: bytes, crc: int = 0xFFFF) -> int:
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def _reference_raw_command(raw: list[int], node_id: int, tid: int, prio: int) -> list[CanFrame]:
    bits = "".join(f"{v & 0xFF:08b}{(v & 0x3FFF) >> 8:06b}" for v in raw)
    bits += "0" * (-len(bits) % 8)
    payload = bytes(int(bits[i : i + 8], 2) for i in range(0, len(bits), 8))
    if len(payload) > 7:
        crc = _crc16_ccitt(payload, _crc16_ccitt(RAW_COMMAND_SIGNATURE.to_bytes(8, "little")))
        payload = crc.to_bytes(2, "little") + payload
    chunks = [payload[i : i + 7] for i in range(0, len(payload), 7)] or [b""]
    can_id = prio << 24 | 1030 << 8 | node_id
    frames = []
    for k, chunk in enumerate(chunks):
        tail = (k == 0) << 7 | (k == len(chunks) - 1) << 6 | (k & 1) << 5 | tid
        frames.append(CanFrame(can_id, chunk + bytes([tail])))
    return frames


def _dronecan_decode(frames: list[CanFrame]) -> Transfer:
    """The dronecan package's own receive path: TransferManager, then from_frames."""
    manager = TransferManager()
    done = None
    for f in frames:
        done = manager.receive_frame(Frame(f.can_id, f.data)) or done
    assert done is not None
    transfer = Transfer()
    transfer.from_frames(done)
    return transfer


def test_reference_signature_matches_dronecan() -> None:
    rc = dronecan.uavcan.equipment.esc.RawCommand
    assert rc.get_data_type_signature() == RAW_COMMAND_SIGNATURE
    assert rc.default_dtid == int(DataType.RAW_COMMAND) == 1030


def test_single_frame_literal_bytes() -> None:
    frames = encode_raw_command([100, -1], source_node_id=10, transfer_id=5)
    # 100 -> 0x64 0b000000, -1 -> 0xFF 0b111111, 4 pad bits; tail SOT|EOT|tid 5
    assert frames == [CanFrame(0x0804060A, bytes([0x64, 0x03, 0xFF, 0xF0, 0xC5]))]


@pytest.mark.parametrize("m", [1, 3, 4, 5, 6, 8, 12, 20])
def test_raw_command_matches_reference_and_dronecan_decoder(m: int) -> None:
    rng = np.random.default_rng(m)
    raw = [int(v) for v in rng.integers(-RAW_MAX, RAW_MAX + 1, m)]
    frames = encode_raw_command(raw, source_node_id=42, transfer_id=m, priority=PRIORITY_HIGH)
    assert frames == _reference_raw_command(raw, 42, m, PRIORITY_HIGH)
    assert all(f.extended and f.can_id < 1 << 29 and len(f.data) <= 8 for f in frames)
    assert len(frames) == (1 if m <= 4 else math.ceil((math.ceil(14 * m / 8) + 2) / 7))
    theirs = _dronecan_decode(frames)
    assert [int(v) for v in theirs.payload.cmd] == raw
    assert theirs.source_node_id == 42 and theirs.transfer_id == m
    got = decode_frames(frames)
    assert got.message == RawCommandMsg(tuple(raw))
    assert (got.source_node_id, got.transfer_id, got.priority) == (42, m, PRIORITY_HIGH)


def test_multi_frame_6_and_8_frame_counts() -> None:
    assert len(encode_raw_command([1] * 6, source_node_id=10, transfer_id=0)) == 2
    assert len(encode_raw_command([1] * 8, source_node_id=10, transfer_id=0)) == 3


def test_decode_reference_frames_from_other_node() -> None:
    raw = [8191, -8191, 0, 17, -17, 4096, -4096, 1]
    got = decode_frames(_reference_raw_command(raw, 99, 31, 0))
    assert got.message == RawCommandMsg(tuple(raw))
    assert (got.source_node_id, got.transfer_id, got.priority) == (99, 31, 0)


def test_esc_status_and_node_status_round_trip() -> None:
    status = EscStatusMsg(7, -1500, 12.5, 48.0, math.nan, 3, 55)
    frames = encode(status, source_node_id=27, transfer_id=3, priority=16)
    assert len(frames) == 3  # 110 bits + CRC
    got = decode_frames(frames)
    assert got.source_node_id == 27
    msg = got.message
    assert isinstance(msg, EscStatusMsg)
    assert (msg.esc_index, msg.rpm, msg.error_count, msg.power_rating_pct) == (7, -1500, 3, 55)
    assert (msg.current_a, msg.voltage_v) == (12.5, 48.0)  # exact in float16
    assert math.isnan(msg.temperature_k)
    theirs = _dronecan_decode(frames).payload
    assert (theirs.esc_index, theirs.rpm, theirs.current) == (7, -1500, 12.5)

    node = NodeStatusMsg(86_400, Health.WARNING, Mode.MAINTENANCE, 2, 0xBEEF)
    frames = encode(node, source_node_id=10, transfer_id=0)
    assert len(frames) == 1 and frames[0].can_id == 31 << 24 | 341 << 8 | 10
    assert decode_frames(frames).message == node


def test_float16_saturates_instead_of_overflowing() -> None:
    frames = encode(EscStatusMsg(0, 10**9, 1e6), source_node_id=20, transfer_id=0)
    msg = decode_frames(frames).message
    assert isinstance(msg, EscStatusMsg)
    assert msg.current_a == 65504.0 and msg.rpm == (1 << 17) - 1


def test_transfer_ids_wrap_per_node_and_type() -> None:
    ids = TransferIds()
    seq = [ids.next(10, DataType.RAW_COMMAND) for _ in range(34)]
    assert seq == list(range(32)) + [0, 1]
    assert ids.next(10, DataType.NODE_STATUS) == 0 and ids.next(11, DataType.RAW_COMMAND) == 0
    frames = encode_raw_command([1, 2, 3, 4, 5, 6], source_node_id=10, transfer_id=33)
    assert decode_frames(frames).transfer_id == 1


def test_assembler_interleaved_senders_and_orphans() -> None:
    a = encode_raw_command(list(range(8)), source_node_id=10, transfer_id=1)
    b = encode_raw_command(list(range(-8, 0)), source_node_id=11, transfer_id=1)
    asm = TransferAssembler()
    out = [asm.feed(f, 0) for pair in zip(a, b, strict=True) for f in pair]
    done = [r.message for r in out if r is not None]
    assert done == [RawCommandMsg(tuple(range(8))), RawCommandMsg(tuple(range(-8, 0)))]
    assert asm.feed(a[1], 0) is None and asm.orphans == 1  # joined mid-transfer
    assert asm.feed(CanFrame(0x123, b"\xc0", extended=False), 0) is None  # not DroneCAN


def test_assembler_expires_partial_transfers() -> None:
    a = encode_raw_command(list(range(8)), source_node_id=10, transfer_id=1)
    asm = TransferAssembler(timeout_s=0.5)
    asm.feed(a[0], 0)
    assert asm.pending == 1
    asm.feed(encode(NodeStatusMsg(1), source_node_id=3, transfer_id=0)[0], 10**9)
    assert asm.pending == 0
    assert asm.feed(a[1], 10**9) is None and asm.orphans == 1


def _corrupt(frames: list[CanFrame], index: int, data: bytes) -> list[CanFrame]:
    out = list(frames)
    out[index] = CanFrame(frames[index].can_id, data)
    return out


def _malformed_cases() -> dict[str, list[CanFrame]]:
    six = encode_raw_command([1, 2, 3, 4, 5, 6], source_node_id=10, transfer_id=2)
    status = encode(EscStatusMsg(1, 2, 3.0), source_node_id=20, transfer_id=4)
    first = six[0].data
    return {
        "bad crc": _corrupt(six, 0, bytes([first[0] ^ 0xFF]) + first[1:]),
        "toggle error": _corrupt(six, 1, six[1].data[:-1] + bytes([six[1].data[-1] ^ 0x20])),
        "short first frame": _corrupt(six, 0, first[:5] + first[-1:]),
        "odd raw length": [CanFrame(six[0].can_id, b"\x01\x02\x03\xc0")],
        "status too short": [CanFrame(status[0].can_id, b"\x01\x02\xc0")],
        "toggle on single frame": [CanFrame(six[0].can_id, b"\x00\x00\xe0")],
        "empty frame": [CanFrame(six[0].can_id, b"")],
        "reserved mode": [
            CanFrame(31 << 24 | 341 << 8 | 5, bytes([0, 0, 0, 0, 5 << 3, 0, 0, 0xC0]))
        ],
    }


@pytest.mark.parametrize("case", sorted(_malformed_cases()))
def test_malformed_transfers_raise(case: str) -> None:
    frames = _malformed_cases()[case]
    asm = TransferAssembler()
    with pytest.raises(MalformedMessage):
        for f in frames:
            asm.feed(f, 0)
    assert asm.pending == 0
    good = encode_raw_command([7], source_node_id=10, transfer_id=9)
    assert asm.feed(good[0], 0) is not None  # the assembler keeps working


def test_force_map_round_trip_within_quantization() -> None:
    fmap = ForceRawMap.from_limits([-60.0, -100.0, -5.0], [100.0, 80.0, 5.0])
    np.testing.assert_array_equal(fmap.u_max_abs, [100.0, 100.0, 5.0])
    rng = np.random.default_rng(0)
    for _ in range(200):
        u = rng.uniform(-1.0, 1.0, 3) * fmap.u_max_abs
        back = fmap.to_force(fmap.to_raw(u))
        assert np.all(np.abs(back - u) <= fmap.quantum_n() / 2 + 1e-12)
    np.testing.assert_array_equal(fmap.to_raw([100.0, -100.0, 2.5]), [8191, -8191, 4096])
    np.testing.assert_array_equal(fmap.to_raw([1e9, -1e9, 0.0]), [8191, -8191, 0])


def test_force_map_deadband_and_input_not_mutated() -> None:
    fmap = ForceRawMap.create([10.0, 10.0], deadband_n=[0.5, 0.0])
    u = np.array([0.4, 0.4])
    np.testing.assert_array_equal(fmap.to_raw(u), [0, 328])
    np.testing.assert_array_equal(u, [0.4, 0.4])


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_force_map_rejects_non_finite(bad: float) -> None:
    fmap = ForceRawMap.create([10.0, 10.0])
    with pytest.raises(NonFiniteCommand, match="finite"):
        fmap.to_raw([1.0, bad])


@pytest.mark.parametrize(
    ("u_max", "dead", "key"),
    [([], 0.0, "u_max_abs"), ([1.0, 0.0], 0.0, "u_max_abs"), ([1.0] * 21, 0.0, "u_max_abs"),
     ([1.0, math.nan], 0.0, "u_max_abs"), ([1.0], -1.0, "deadband_n")],
)  # fmt: skip
def test_force_map_config_errors_name_the_key(u_max: list[float], dead: float, key: str) -> None:
    with pytest.raises(ValueError, match=key):
        ForceRawMap.create(u_max, dead)


def test_force_map_wrong_length() -> None:
    with pytest.raises(ValueError, match="shape"):
        ForceRawMap.create([1.0, 1.0]).to_raw([1.0])


def _first_frames(n: int) -> list[CanFrame]:
    """First frames of n never-ending 3-frame RawCommand transfers, each its own session."""
    out = []
    for i in range(n):
        node, prio = 1 + i % 127, (i // 127) % 32
        frames = encode_raw_command(
            list(range(8)), source_node_id=node, transfer_id=i, priority=prio
        )
        out.append(frames[0])
    return out


def test_assembler_keeps_one_transfer_per_session() -> None:
    asm = TransferAssembler()
    a = encode_raw_command(list(range(8)), source_node_id=10, transfer_id=1)
    b = encode_raw_command(list(range(8, 16)), source_node_id=10, transfer_id=2, priority=3)
    asm.feed(a[0], 0)
    asm.feed(b[0], 0)  # same (node, type): replaces the first
    assert asm.pending == 1
    assert asm.feed(a[1], 0) is None and asm.orphans == 1  # another transfer ID / CAN ID
    assert asm.feed(b[1], 0) is None
    got = asm.feed(b[2], 0)
    assert got is not None and got.message == RawCommandMsg(tuple(range(8, 16)))


def test_assembler_caps_pending_transfers_and_counts_evictions() -> None:
    asm = TransferAssembler(max_pending=16)
    for f in _first_frames(400):
        asm.feed(f, 0)
    assert asm.pending == 16
    assert asm.evicted == 400 - 16  # every start beyond the cap pushed the oldest out
    good = encode_raw_command(list(range(8)), source_node_id=10, transfer_id=7)
    assert [asm.feed(f, 0) for f in good][-1] is not None  # a real sender still gets through


def test_assembler_expiry_counts_and_survives_a_clock_step_back() -> None:
    asm = TransferAssembler(timeout_s=0.5)
    for i, f in enumerate(_first_frames(50)):
        asm.feed(f, i * 1_000_000)
    asm.feed(_first_frames(1)[0], 10**6 * 300)  # node 1 restarted at 0.3 s: kept
    assert asm.pending == 50
    asm.feed(encode(NodeStatusMsg(1), source_node_id=3, transfer_id=0)[0], 10**6 * 549)
    # started at 1..48 ms: stale; 49 ms: exactly the timeout, kept; node 1 restarted: kept
    assert asm.expired == 48 and asm.pending == 2
    asm.feed(encode(NodeStatusMsg(1), source_node_id=3, transfer_id=0)[0], 0)  # clock stepped back
    assert asm.pending == 2


@pytest.mark.parametrize("bad", [{"timeout_s": 0.0}, {"timeout_s": math.nan}, {"max_pending": 0}])
def test_assembler_refuses_unbounded_settings(bad: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        TransferAssembler(**bad)  # type: ignore[arg-type]


def test_a_resent_transfer_only_changes_its_tail_bytes() -> None:
    for m in (2, 8, 20):
        a = encode_raw_command(list(range(m)), source_node_id=10, transfer_id=3)
        b = encode_raw_command(list(range(m)), source_node_id=10, transfer_id=30)
        assert with_transfer_id(a, 30) == b
        assert decode_frames(with_transfer_id(a, 62)).transfer_id == 30  # wraps like next()
