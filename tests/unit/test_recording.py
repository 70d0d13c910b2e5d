"""MCAP recordings: the mcap package reads and validates them, every channel is there, every
channel decodes from the file's own schemas, and the messages agree with the CSV."""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.faults import injection_plan
from ftcap_hil.core.status import AllocatorStatus, Mode
from ftcap_hil.report.flight import FlightRecorder
from ftcap_hil.report.recording import CHANNELS, LogLine, write_mcap
from ftcap_hil.report.records import RunRecord, write_csv
from ftcap_hil.runtime.offline import run_mode
from tests.support.no_transports import env_without_transports
from tests.support.records import float_rows
from tests.support.ros2_reference import read_mcap

ROOT = Path(__file__).resolve().parents[2]


@functools.cache
def record() -> RunRecord:
    sc = load_scenario("paper-4.2-ex1")
    return run_mode(dataclasses.replace(sc, duration_s=40.0), Mode.FTCAP)


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, float]]]:
    out = tmp_path_factory.mktemp("rec")
    write_csv(record(), out / "timeseries.csv")
    write_mcap(record(), out / "run.mcap", logs=[LogLine(1.0, "hello from the run")])
    return out / "run.mcap", float_rows(out / "timeseries.csv")


def test_the_mcap_package_reads_and_validates_it(files: tuple[Path, Any]) -> None:
    path, _ = files
    with open(path, "rb") as fh:
        summary = make_reader(fh, validate_crcs=True).get_summary()
    with open(path, "rb") as fh:
        sequential = sum(1 for _ in NonSeekingReader(fh, validate_crcs=True).iter_messages())
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == sequential > 0
    assert {c.topic: c.message_encoding for c in summary.channels.values()} == dict.fromkeys(
        CHANNELS, "cdr"
    )
    assert {summary.schemas[c.schema_id].name for c in summary.channels.values()} == set(
        CHANNELS.values()
    )


def test_every_channel_holds_messages(files: tuple[Path, Any]) -> None:
    got = read_mcap(files[0])
    assert sorted(got) == sorted(CHANNELS)
    n = len(record().t)
    assert all(
        len(got[t]) == n
        for t in ("/ftcap/odometry", "/ftcap/allocator/status", "/ftcap/thrusters/command")
    )


def test_the_messages_agree_with_the_csv(files: tuple[Path, list[dict[str, float]]]) -> None:
    path, rows = files
    got = read_mcap(path)
    m = record().scenario.thrusters.m
    for row, (stamp, odom), (_, cmd), (_, st), (_, dem) in zip(
        rows, got["/ftcap/odometry"], got["/ftcap/thrusters/command"],
        got["/ftcap/allocator/status"], got["/ftcap/wrench/demanded"], strict=True,
    ):  # fmt: skip
        assert stamp == pytest.approx(row["t"] * 1e9, abs=1e3)  # the CSV has 9 digits
        p = odom.pose.pose
        assert (p.position.x, p.position.y) == pytest.approx((row["east"], row["north"]), rel=1e-8)
        yaw = 2 * math.atan2(p.orientation.z, p.orientation.w)
        assert math.remainder(math.pi / 2 - yaw - row["psi"], 2 * math.pi) == pytest.approx(
            0, abs=1e-7
        )
        assert odom.twist.twist.angular.z == pytest.approx(-row["r"], rel=1e-8)
        u = [row[f"u_{i}"] for i in range(1, m + 1)]
        np.testing.assert_allclose(cmd.data, u, rtol=1e-8)
        np.testing.assert_allclose(
            st.delta_hat, [row[f"delta_hat_{i}"] for i in range(1, m + 1)], rtol=1e-8
        )
        assert st.faulty.tolist() == [row[f"faulty_{i}"] == 1.0 for i in range(1, m + 1)]
        assert st.dead.tolist() == [row[f"dead_{i}"] == 1.0 for i in range(1, m + 1)]
        assert (dem.wrench.force.x, -dem.wrench.force.y, -dem.wrench.torque.z) == pytest.approx(
            (row["v_dem_1"], row["v_dem_2"], row["v_dem_3"]), rel=1e-8
        )
        if "delta_std_1" in row and math.isfinite(row["delta_std_1"]):
            lower = np.clip(
                np.array(
                    [row[f"delta_hat_{i}"] - 2 * row[f"delta_std_{i}"] for i in range(1, m + 1)]
                ),
                0,
                1,
            )
            np.testing.assert_allclose(st.delta_lower, lower, rtol=1e-7, atol=1e-9)


def test_faults_and_log_lines(files: tuple[Path, Any]) -> None:
    got = read_mcap(files[0])
    sc = record().scenario
    plan = injection_plan(sc.faults, sc.duration_s)
    faults = [(t, f.thruster, f.kind) for t, f in got["/ftcap/fault/inject"]]
    assert faults == [(round(i.at_s * 1e9), i.thruster, i.kind.value) for i in plan] and plan
    lines = [log.msg for _, log in got["/rosout"]]
    assert "hello from the run" in lines
    assert sum(line.startswith("fault injected") for line in lines) == len(plan)
    raised = np.flatnonzero(np.diff(record().columns["faulty_1"]) > 0)
    assert sum(line == "thruster 1 flagged faulty" for line in lines) == len(raised)


def test_the_layout_shows_channels_the_recordings_have() -> None:
    layout = json.loads((ROOT / "docs" / "foxglove-layout.json").read_text())
    text = json.dumps(layout["configById"])
    topics = set(re.findall(r'"(/[a-z_/]+?)(?:\.|")', text)) - {
        "/move_base_simple/goal",
        "/clicked_point",
        "/initialpose",
    }
    assert topics and topics <= set(CHANNELS), topics - set(CHANNELS)
    panels = set(re.findall(r'"([A-Za-z0-9]+![a-z0-9]+)"', json.dumps(layout["layout"])))
    assert panels <= set(layout["configById"])


def test_a_ground_station_record(tmp_path: Path) -> None:
    sc = load_scenario("paper-4.2-ex1")
    rec = FlightRecorder(sc)
    status = AllocatorStatus.checked(
        delta_hat=(0.9, 1.0, 1.0, 1.0), f_hat=(0.0,) * 4, delta_std=(0.05,) * 4,
        faulty=(True, False, False, False),
    )  # fmt: skip
    pose = np.array([1.0, 2.0, 0.1, 0.0, 0.0, 0.0])
    rec.add(0.0, pose, np.zeros(3), np.array([1.0, 0.0, 0.0]), None, None)  # nothing heard yet
    rec.add(0.5, pose, np.zeros(3), np.array([1.0, 0.0, 0.0]), status, [0.1, 0.2, 0.3, 0.4])
    counts = write_mcap(rec.finish("ftcap", 0.5), tmp_path / "run.mcap")
    got = read_mcap(tmp_path / "run.mcap")
    assert counts["/ftcap/allocator/status"] == len(got["/ftcap/allocator/status"]) == 2
    first, second = (st for _, st in got["/ftcap/allocator/status"])
    assert np.isnan(first.delta_hat).all() and second.delta_hat.tolist() == [0.9, 1.0, 1.0, 1.0]
    assert second.faulty.tolist() == [True, False, False, False]
    np.testing.assert_allclose(second.delta_upper, [1.0] * 4)
    assert got["/ftcap/thrusters/command"][1][1].data.tolist() == [0.1, 0.2, 0.3, 0.4]


def test_simulate_writes_run_mcap_without_the_transports(tmp_path: Path) -> None:
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "ftcap_hil", "simulate", "paper-4.1", "--mode", "ftcap",
           "--out", str(out), "--no-plots", "--quiet", "--mcap"]  # fmt: skip
    env = env_without_transports(tmp_path / "refuse")
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    for mode in ("none", "ftcap"):
        got = read_mcap(out / mode / "run.mcap")
        with open(out / mode / "timeseries.csv") as fh:
            rows = sum(1 for _ in fh) - 1
        assert len(got["/ftcap/allocator/status"]) == rows > 0
        assert "/ftcap/odometry" not in got  # the linear plant has no pose
        assert ("/ftcap/fault/inject" in got) == (mode == "ftcap")  # none flies without faults
