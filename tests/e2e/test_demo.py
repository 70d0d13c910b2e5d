"""End-to-end: ``ftcap-hil demo`` starts the CAN hub, vessel, allocator and ground station as
processes on loopback, flies example 1 of the paper through its first fault onset (12 s),
and cleans up after itself, also when interrupted or when a child dies."""

from __future__ import annotations

import json
import os
import signal
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from ftcap_hil.report.recording import CHANNELS
from ftcap_hil.runtime.processes import Child
from tests.e2e.demo_support import (
    child_pids,
    ftcap_hil,
    is_ours_and_alive,
    reap,
    start,
    stderr_of,
    wait_for,
)
from tests.support.records import float_rows
from tests.support.ros2_reference import read_mcap

pytestmark = pytest.mark.e2e

DURATION_S = 30.0  # example 1: thruster 1 becomes delta 0.9, bias 0.01 N at 12 s
CHILDREN = {"can_hub", "allocator", "vessel", "gcs"}


@dataclass
class DemoRun:
    out: Path
    returncode: int
    stdout: str
    stderr: str


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DemoRun]:
    out = tmp_path_factory.mktemp("demo") / "out"
    argv = ftcap_hil("demo", "--duration", str(DURATION_S), "--out", str(out), "--mcap")
    proc = start("demo", argv, out.parent)
    try:
        code = proc.wait(DURATION_S + 150)
        yield DemoRun(out, code, proc.output(), stderr_of(proc))
    finally:
        reap(proc, out)


def _rows(out: Path) -> list[dict[str, float]]:
    return float_rows(out / "ftcap" / "timeseries.csv")


@pytest.mark.timeout(300)
def test_demo_completes_and_writes_the_simulator_outputs(demo: DemoRun) -> None:
    assert demo.returncode == 0, demo.stderr[-3000:]
    results = json.loads((demo.out / "results.json").read_text())
    assert list(results["modes"]) == ["ftcap"]  # the allocator's mode, read over MAVLink
    assert results["phases"] == [[0.0, 12.0], [12.0, DURATION_S]]
    pngs = {p.name for p in demo.out.glob("*.png")}
    assert {"positions.png", "effectiveness.png", "bias.png", "xy_path.png"} <= pngs
    assert len(_rows(demo.out)) > 0.9 * DURATION_S / 0.2827
    assert "tracking rms" in demo.stdout and str(demo.out) in demo.stdout
    # the demo explains itself: per phase what was injected, how the estimate did, a verdict
    assert "VERDICT: every fault phase handled" in demo.stdout, demo.stdout[-3000:]
    assert "WEAK thruster 1" in demo.stdout, demo.stdout[-3000:]
    assert {f"{name}.log" for name in CHILDREN} <= {p.name for p in (demo.out / "logs").iterdir()}


@pytest.mark.timeout(300)
def test_the_demo_says_how_the_flight_goes_every_5_s(demo: DemoRun) -> None:
    """A progress line in every 5 s of mission time, on the ground station's clock. Judged
    on the mission times the lines carry, not on when they were printed: each window
    [5k, 5k + 5) s of the 30 s flown holds a line (a line is due at the first cycle at or
    after each 5 s mark; only a stall of the ground station over ~5 s could empty a window,
    and that would end the flight on its odometry timeout); the lines after the 12 s onset
    name the injection and the allocator's mode."""
    lines = [ln for ln in demo.stdout.splitlines() if ln.startswith("demo: progress: t ")]
    times = [float(ln.split()[3].split("/")[0]) for ln in lines]
    assert times == sorted(times), times
    windows = {int(t // 5.0) for t in times}
    assert set(range(int(DURATION_S // 5.0))) <= windows, (times, demo.stdout[-2000:])
    after = [ln for ln, t in zip(lines, times, strict=True) if t >= 15.0]
    assert after and all("WEAK thruster 1" in ln and "allocator ftcap" in ln for ln in after)


@pytest.mark.timeout(300)
def test_faults_are_injected_and_identified(demo: DemoRun) -> None:
    results = json.loads((demo.out / "results.json").read_text())
    injections = results["modes"]["ftcap"]["injections"]
    assert [(i["kind"], i["thruster"], i["result"]) for i in injections] == [
        ("WEAK", 1, "ACCEPTED"),
        ("BIAS", 1, "ACCEPTED"),
    ]
    assert all(12.0 <= i["sent_at_s"] < 13.0 for i in injections)
    rows = _rows(demo.out)
    last = rows[-1]
    assert (last["delta_1"], last["f_1"]) == (0.9, 0.01)  # the truth recorded
    before = [r for r in rows if 10.0 <= r["t"] < 12.0]
    assert all(abs(r["delta_hat_1"] - 1.0) < 0.05 for r in before)
    tail = [r for r in rows if r["t"] > DURATION_S - 3.0]
    for i in range(1, 5):
        assert all(abs(r[f"delta_hat_{i}"] - r[f"delta_{i}"]) < 0.1 for r in tail), i


@pytest.mark.timeout(300)
def test_tracking_stays_bounded(demo: DemoRun) -> None:
    results = json.loads((demo.out / "results.json").read_text())
    mode = results["modes"]["ftcap"]
    assert mode["bounded"]
    after_step = mode["phases"][1]
    assert after_step["tracking_max"] < 3.0  # a 2 m step of the reference at 12 s
    last = _rows(demo.out)[-1]
    assert abs(last["north"] - 2.0) < 0.3 and abs(last["east"]) < 0.3


@pytest.mark.timeout(300)
def test_no_child_is_left_running(demo: DemoRun) -> None:
    pids = child_pids(demo.out)
    assert set(pids) == CHILDREN
    assert not [name for name, pid in pids.items() if is_ours_and_alive(pid)]


def _start_demo(out: Path) -> Child:
    argv = ftcap_hil("demo", "--duration", "60", "--out", str(out), "--no-plots")
    return start("demo", argv, out.parent)


def _all_started(out: Path) -> bool:
    return set(child_pids(out)) == CHILDREN


@pytest.mark.timeout(120)
def test_ctrl_c_stops_every_child(tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = _start_demo(out)
    try:
        assert wait_for(lambda: _all_started(out), 30.0)
        assert wait_for(lambda: (out / "logs" / "gcs.log").stat().st_size > 0, 30.0)
        proc.send(signal.SIGINT)
        assert proc.wait(60) == 130
        pids = child_pids(out)
        assert not [name for name, pid in pids.items() if is_ours_and_alive(pid)]
    finally:
        reap(proc, out)


@pytest.mark.timeout(120)
def test_a_dying_child_stops_the_demo_with_an_error(tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = _start_demo(out)
    try:
        assert wait_for(lambda: _all_started(out), 30.0)
        vessel = child_pids(out)["vessel"]
        os.kill(vessel, signal.SIGKILL)
        assert proc.wait(60) == 1
        stderr = stderr_of(proc)
        assert "vessel (pid" in stderr and "exited early" in stderr
        pids = child_pids(out)
        assert not [name for name, pid in pids.items() if is_ours_and_alive(pid)]
    finally:
        reap(proc, out)


@pytest.mark.timeout(300)
def test_the_demos_mcap_holds_every_channel_and_the_csvs_values(demo: DemoRun) -> None:
    assert demo.returncode == 0, demo.stderr[-3000:]
    got = read_mcap(demo.out / "ftcap" / "run.mcap")  # CRCs checked by the mcap reader
    assert sorted(got) == sorted(CHANNELS)
    rows = _rows(demo.out)
    status = [st for _, st in got["/ftcap/allocator/status"]]
    assert len(status) == len(rows) > 0
    for row, st, (stamp, odom) in zip(rows, status, got["/ftcap/odometry"], strict=True):
        assert stamp == pytest.approx(row["t"] * 1e9, abs=1e3)  # the CSV has 9 digits
        assert odom.pose.pose.position.y == pytest.approx(row["north"], rel=1e-8, abs=1e-12)
        assert st.delta_hat[0] == pytest.approx(row["delta_hat_1"], rel=1e-8, nan_ok=True)
