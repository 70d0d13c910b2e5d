"""vcan0 works where run_with_vcan runs a command: on this host, or in a VM (see README.md).

The smoke test runs smoke_peers.py there: a python-can sender and receiver, two processes on
vcan0, with ``candump -L`` logging the bus into a folder shared with the host, which this test
then parses.
"""

from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path

import pytest

from tests.vcan import smoke_peers, vcanrun

pytestmark = pytest.mark.vcan

REPO = Path(__file__).resolve().parents[2]
N_FRAMES = 200
TIMEOUT_S = 600.0  # the VM boots in ~3 s, but Python in it runs ~18x slower than here
CANDUMP_LINE = re.compile(r"^\((\d+\.\d+)\) (\w+) ([0-9A-F]{3}|[0-9A-F]{8})#([0-9A-F]*)$")


@pytest.fixture(scope="module", autouse=True)
def _vcan_available() -> None:
    reason = vcanrun.unavailable_reason()
    if reason is not None:
        pytest.skip(f"no vcan0 on this host and no VM to provide one: {reason}")


def parse_candump(text: str) -> list[tuple[float, str, int, bool, bytes]]:
    """``candump -L`` lines -> (stamp_s, channel, can id, extended, data); rejects others."""
    frames = []
    for line in text.splitlines():
        match = CANDUMP_LINE.match(line)
        assert match, f"not a candump -L line: {line!r}"
        stamp, channel, can_id, data = match.groups()
        frames.append(
            (float(stamp), channel, int(can_id, 16), len(can_id) == 8, bytes.fromhex(data))
        )
    return frames


def test_two_processes_exchange_frames_over_vcan0(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    argv = [sys.executable, str(Path(smoke_peers.__file__)), "run", str(out), str(N_FRAMES)]

    result = vcanrun.run_with_vcan(argv, cwd=REPO, timeout_s=TIMEOUT_S, writable=[out])

    assert result.returncode == 0, f"{result.mode.value}:\n{result.output}"
    expected = smoke_peers.expected_frames(N_FRAMES)
    received = [(i, bytes.fromhex(d)) for i, d in json.loads((out / "received.json").read_text())]
    assert received == expected
    logged = parse_candump((out / "candump.log").read_text())
    assert {channel for _, channel, _, _, _ in logged} == {"vcan0"}
    assert any(not ext and can_id == smoke_peers.SYNC_ID for _, _, can_id, ext, _ in logged)
    data_frames = [(can_id, data) for _, _, can_id, ext, data in logged if ext]
    assert data_frames == expected
    stamps = [stamp for stamp, *_ in logged]
    assert stamps == sorted(stamps)


def test_the_smoke_check_fails_without_its_bus(tmp_path: Path) -> None:
    argv = [sys.executable, str(Path(smoke_peers.__file__)), "run", str(tmp_path), "5", "vcan9"]

    result = vcanrun.run_with_vcan(argv, cwd=REPO, timeout_s=TIMEOUT_S, writable=[tmp_path])

    assert result.returncode != 0
    assert "a peer exited" in result.output
    assert not (tmp_path / "received.json").exists()


def test_exit_status_output_and_vcan0_come_back(tmp_path: Path) -> None:
    script = "ip -br link show vcan0; echo artifact > result.txt; echo to-stderr >&2; exit 7"

    result = vcanrun.run_with_vcan(["sh", "-c", script], cwd=tmp_path, timeout_s=TIMEOUT_S)

    assert result.returncode == 7
    assert re.search(r"^vcan0\s+\S+\s+<[^>]*\bUP\b", result.output, re.MULTILINE), result.output
    assert "to-stderr" in result.output
    assert (tmp_path / "result.txt").read_text() == "artifact\n"


def test_timeout_kills_the_run_and_says_so(tmp_path: Path) -> None:
    with pytest.raises(vcanrun.VcanTimeout, match="still running"):
        vcanrun.run_with_vcan(["sleep", "600"], cwd=tmp_path, timeout_s=8.0)

    assert _children_named(("qemu-system-x86_64", "sleep")) == []


def _children_named(names: tuple[str, ...]) -> list[str]:
    """Commands of this process's live children whose name is one of ``names``."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:  # the process ended meanwhile
            continue
        name, rest = text[text.index("(") + 1 : text.rindex(")")], text[text.rindex(")") + 2 :]
        state, ppid = rest.split()[:2]
        if int(ppid) == os.getpid() and state != "Z" and name in names:
            found.append(name)
    return found
