"""MCAP recordings: the mcap package reads and validates them, every channel is there, every
channel decodes from the file's own schemas, and the messages agree with the CSV."""

from __future__ import annotations

import csv
import dataclasses
import functools
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.faults import injection_plan
from ftcap_hil.core.status import Mode
from ftcap_hil.report.recording import CHANNELS, LogLine, write_mcap
from ftcap_hil.report.records import RunRecord, write_csv
from ftcap_hil.runtime.offline import run_mode

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
    with open(out / "timeseries.csv") as fh:
        rows = [{k: float(v) for k, v in row.items()} for row in csv.DictReader(fh)]
    return out / "run.mcap", rows


def messages(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """topic -> [(log time, rosbags object)], decoded with the file's own schemas."""
    out: dict[str, list[tuple[int, Any]]] = {}
    store = get_typestore(Stores.EMPTY)
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh, validate_crcs=True).iter_messages():
            assert schema is not None and schema.encoding == "ros2msg"
            if schema.name not in store.types:
                store.register(schema_types(schema.name, schema.data.decode()))
            obj = store.deserialize_cdr(message.data, schema.name)
            out.setdefault(channel.topic, []).append((message.log_time, obj))
    return out


def schema_types(name: str, text: str) -> dict[str, Any]:
    """rosbags' types of a ros2msg schema: the main .msg, then ``MSG: pkg/Name`` sections."""
    sections = re.split(r"^={80}\nMSG: (\S+)\n", text, flags=re.M)
    types = get_types_from_msg(sections[0], name)
    for dep, body in zip(sections[1::2], sections[2::2], strict=True):
        pkg, short = dep.split("/")
        types |= get_types_from_msg(body, f"{pkg}/msg/{short}")
    return types


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
    got = messages(files[0])
    assert sorted(got) == sorted(CHANNELS)
    n = len(record().t)
    assert all(
        len(got[t]) == n
        for t in ("/ftcap/odometry", "/ftcap/allocator/status", "/ftcap/thrusters/command")
    )


def test_the_messages_agree_with_the_csv(files: tuple[Path, list[dict[str, float]]]) -> None:
    path, rows = files
    got = messages(path)
    m = record().scenario.thrusters.m
    for row, (stamp, odom), (_, cmd), (_, st), (_, dem) in zip(
        rows, got["/ftcap/odometry"], got["/ftcap/thrusters/command"],
        got["/ftcap/allocator/status"], got["/ftcap/wrench/demanded"], strict=True,
    ):  # fmt: skip
        assert stamp == round(row["t"] * 1e9)
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
    got = messages(files[0])
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
