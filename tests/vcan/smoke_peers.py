"""The processes of the vcan smoke test; runs where vcan0 is up (see vcanrun.py).

    python smoke_peers.py run OUT_DIR N [CHANNEL]   candump, a receiver and a sender; wait
    python smoke_peers.py recv OUT_DIR N [CHANNEL]  receive N frames, write received.json
    python smoke_peers.py send N [CHANNEL]          send the N frames of expected_frames(N)

CHANNEL defaults to vcan0.

``run`` leaves OUT_DIR/candump.log (``candump -L``) and OUT_DIR/received.json for the host
to check, and exits non-zero if a peer failed.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from subprocess import Popen

CHANNEL = "vcan0"
SYNC_ID = 0x7FF  # standard id, only used to see that candump is listening
STEP_TIMEOUT_S = 240.0  # the guest runs Python ~18x slower than the host
IDLE_TIMEOUT_S = 15.0  # the receiver gives up this long after the last frame


def expected_frames(n: int) -> list[tuple[int, bytes]]:
    """N (29-bit id, payload) pairs with every payload length 0..8, as DroneCAN uses."""
    return [(0x10000 + i, bytes((i + k) & 0xFF for k in range(i % 9))) for i in range(n)]


def send(n: int, channel: str) -> int:
    import can  # imported here: the orchestrator itself needs no python-can

    with can.Bus(interface="socketcan", channel=channel) as bus:
        for arbitration_id, data in expected_frames(n):
            msg = can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=True)
            for attempt in range(100):
                try:
                    bus.send(msg, timeout=1.0)
                    break
                except can.CanOperationError:  # ENOBUFS: the queue is full, let it drain
                    time.sleep(0.01 * (attempt + 1))
            else:
                print(f"send: gave up on frame {arbitration_id:#x}", file=sys.stderr)
                return 1
    return 0


def recv(out_dir: Path, n: int, channel: str) -> int:
    import can

    got: list[tuple[int, bytes]] = []
    with can.Bus(interface="socketcan", channel=channel) as bus:
        (out_dir / "recv.ready").touch()
        deadline = time.monotonic() + STEP_TIMEOUT_S
        while len(got) < n and time.monotonic() < deadline:
            msg = bus.recv(timeout=1.0)
            if msg is not None and msg.is_extended_id:
                got.append((msg.arbitration_id, bytes(msg.data)))
                deadline = time.monotonic() + IDLE_TIMEOUT_S
    (out_dir / "received.json").write_text(json.dumps([[i, d.hex()] for i, d in got]))
    if got != expected_frames(n):
        print(f"recv: got {len(got)} frames, not the {n} expected ones", file=sys.stderr)
        return 1
    return 0


def _wait_for(what: str, predicate: Callable[[], bool], alive: list[Popen[bytes]]) -> None:
    deadline = time.monotonic() + STEP_TIMEOUT_S
    while not predicate():
        if any(p.poll() is not None for p in alive):
            raise RuntimeError(f"run: a peer exited while waiting for {what}")
        if time.monotonic() > deadline:
            raise TimeoutError(f"run: no {what} after {STEP_TIMEOUT_S:g} s")
        time.sleep(0.2)


def run(out_dir: Path, n: int, channel: str) -> int:
    """candump, then the receiver, then the sender; 0 if both peers succeeded."""
    log = out_dir / "candump.log"
    me = [sys.executable, __file__]
    with open(log, "wb") as log_file:
        candump = Popen(["candump", "-L", channel], stdout=log_file)
    peers = [candump]

    def candump_listens() -> bool:
        subprocess.run(["cansend", channel, f"{SYNC_ID:03X}#53594E43"], check=False)
        return f" {channel} {SYNC_ID:03X}#" in log.read_text()

    try:
        _wait_for("sync frame in candump.log", candump_listens, peers)
        receiver = Popen([*me, "recv", str(out_dir), str(n), channel])
        peers.append(receiver)
        _wait_for("ready receiver", (out_dir / "recv.ready").exists, peers)
        sender = Popen([*me, "send", str(n), channel])
        peers.append(sender)
        codes = {"send": sender.wait(STEP_TIMEOUT_S), "recv": receiver.wait(STEP_TIMEOUT_S)}
        time.sleep(0.5)  # let candump print the last frames
    except (RuntimeError, TimeoutError, subprocess.TimeoutExpired) as e:
        print(e, file=sys.stderr)
        return 1
    finally:
        for peer in peers:
            if peer.poll() is None:
                peer.send_signal(signal.SIGTERM)
                peer.wait(10)
    print(f"run: exit codes {codes}")
    return 0 if codes == {"send": 0, "recv": 0} else 1


def main(argv: list[str]) -> int:
    command, args = (argv[0], argv[1:]) if argv else ("", [])
    if command in ("run", "recv") and len(args) in (2, 3):
        job = run if command == "run" else recv
        return job(Path(args[0]), int(args[1]), args[2] if len(args) == 3 else CHANNEL)
    if command == "send" and len(args) in (1, 2):
        return send(int(args[0]), args[1] if len(args) == 2 else CHANNEL)
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
