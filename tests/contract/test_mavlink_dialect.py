"""The ftcap MAVLink dialect: free message ids, pinned wire format, cached generation."""

from __future__ import annotations

import importlib.util
import os
import re
import struct
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from bridges.mavlink import dialect as mavlink_dialect
from tests.support.mavlink_peers import DIALECT


def _message_ids(xml: Path) -> dict[int, str]:
    root = ET.parse(xml).getroot()
    return {int(m.get("id", -1)): m.get("name", "") for m in root.iter("message")}


def test_our_ids_are_in_our_range_and_free_in_every_bundled_dialect() -> None:
    ours = _message_ids(mavlink_dialect.XML)
    standard = mavlink_dialect.STANDARD_IDS
    own = {i: n for i, n in ours.items() if i not in standard}
    assert set(own.values()) == {
        "WRENCH_SETPOINT",
        "FTCAP_STATUS",
        "FTCAP_ESC_STATUS",
        "FTCAP_THRUST",
    }
    assert all(i in mavlink_dialect.MESSAGE_IDS for i in own)
    assert {i: ours[i] for i in standard} == standard
    # (ftcap.xml itself is there once `python -m bridges.mavlink.dialect --install` ran)
    bundled = sorted(
        p
        for p in mavlink_dialect.pymavlink_definitions_dir().glob("*.xml")
        if p.name != "ftcap.xml"
    )
    assert any(p.name == "all.xml" for p in bundled)
    for xml in bundled:
        clash = set(own) & set(_message_ids(xml))
        assert not clash, f"{xml.name} also uses message ids {sorted(clash)}"


def test_standard_esc_messages_match_common_xml_on_the_wire() -> None:
    # The CRC extra of MAVLink's own common.xml ESC_INFO / ESC_STATUS (251, 10): the same
    # fields in the same order, so QGroundControl and MAVSDK decode ours.
    assert DIALECT.MAVLINK_MSG_ID_ESC_INFO == 290
    assert DIALECT.MAVLink_esc_info_message.crc_extra == 251
    assert DIALECT.MAVLINK_MSG_ID_ESC_STATUS == 291
    assert DIALECT.MAVLink_esc_status_message.crc_extra == 10


def test_wire_format_is_pinned() -> None:
    # crc_extra hashes names and types of the fields: a change here breaks every peer
    # built from the old XML, so it must be deliberate (update these numbers with it).
    assert DIALECT.MAVLINK_MSG_ID_WRENCH_SETPOINT == 52800
    assert DIALECT.MAVLink_wrench_setpoint_message.crc_extra == 232
    assert DIALECT.MAVLINK_MSG_ID_FTCAP_STATUS == 52801
    assert DIALECT.MAVLink_ftcap_status_message.crc_extra == 25  # extensions do not count
    assert DIALECT.MAVLINK_MSG_ID_FTCAP_THRUST == 52803
    assert DIALECT.MAVLink_ftcap_thrust_message.crc_extra == 196
    assert DIALECT.WIRE_PROTOCOL_VERSION == "2.0"


def test_frames_are_mavlink2_and_round_trip() -> None:
    mav = DIALECT.MAVLink(None, srcSystem=255, srcComponent=190)
    frame = DIALECT.MAVLink_wrench_setpoint_message(7, 1, 191, 1.5, -2.0, 3.25).pack(mav)
    assert frame[0] == DIALECT.PROTOCOL_MARKER_V2
    decoded = DIALECT.MAVLink(None).parse_buffer(frame)[0]
    assert (decoded.surge, decoded.sway, decoded.yaw, decoded.target_component) == (
        1.5,
        -2.0,
        3.25,
        191,
    )


def test_generation_is_deterministic_and_includes_common() -> None:
    first = mavlink_dialect.render()
    assert first == mavlink_dialect.render()
    assert "MAVLINK_MSG_ID_ODOMETRY = 331" in first
    assert "MAVLINK_MSG_ID_WRENCH_SETPOINT = 52800" in first


def test_load_caches_by_content(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("FTCAP_MAVLINK_CACHE", str(tmp_path / "cache"))
    xml = tmp_path / "ftcap.xml"
    xml.write_text(mavlink_dialect.XML.read_text())
    before = set(sys.modules)
    try:
        module = mavlink_dialect.load(xml)
        cached = list((tmp_path / "cache").glob("ftcap_*.py"))
        assert [Path(str(module.__file__))] == cached
        mtime = cached[0].stat().st_mtime_ns
        assert mavlink_dialect.load(xml).MAVLINK_MSG_ID_FTCAP_STATUS == 52801
        assert cached[0].stat().st_mtime_ns == mtime  # not regenerated
        xml.write_text(re.sub("Cycle state.", "Cycle state bits.", xml.read_text()))
        mavlink_dialect.load(xml)
        assert len(list((tmp_path / "cache").glob("ftcap_*.py"))) == 2  # new content, new key
        assert not list((tmp_path / "cache").glob(".ftcap-*"))  # no temporaries left
    finally:
        for name in set(sys.modules) - before:
            del sys.modules[name]


def test_cache_dir_precedence(monkeypatch) -> None:
    monkeypatch.setenv("FTCAP_MAVLINK_CACHE", "/x/explicit")
    monkeypatch.setenv("XDG_CACHE_HOME", "/x/xdg")
    assert mavlink_dialect.cache_dir() == Path("/x/explicit")
    monkeypatch.delenv("FTCAP_MAVLINK_CACHE")
    assert mavlink_dialect.cache_dir() == Path("/x/xdg/ftcap-hil/mavlink")


def test_mavgen_failure_is_reported(tmp_path) -> None:
    broken = tmp_path / "ftcap.xml"
    broken.write_text(mavlink_dialect.XML.read_text().replace('id="52801"', 'id="52800"'))
    with pytest.raises(RuntimeError, match="mavgen failed"):
        mavlink_dialect.render(broken)


def _fresh_load(xml: Path) -> Path:
    """Load ``xml`` as a dialect of its own (not the cached module) and return its file."""
    before = set(sys.modules)
    try:
        return Path(str(mavlink_dialect.load(xml).__file__))
    finally:
        for name in set(sys.modules) - before:
            del sys.modules[name]


def _copy_xml(tmp_path: Path) -> Path:
    xml = tmp_path / "ftcap.xml"
    xml.write_text(mavlink_dialect.XML.read_text().replace("Cycle state.", "Cycle state (t)."))
    return xml


def test_a_new_cache_directory_is_private(tmp_path, monkeypatch) -> None:
    cache = tmp_path / "cache" / "mavlink"
    monkeypatch.setenv("FTCAP_MAVLINK_CACHE", str(cache))
    path = _fresh_load(_copy_xml(tmp_path))
    assert path.parent == cache
    assert cache.stat().st_mode & 0o777 == 0o700
    assert path.stat().st_mode & 0o077 == 0  # the module is not even readable by others


@pytest.mark.parametrize("kind", ["world-writable", "symlink"])
def test_a_shared_or_planted_cache_is_never_imported_from(tmp_path, monkeypatch, kind) -> None:
    xml = _copy_xml(tmp_path)
    monkeypatch.setenv("FTCAP_MAVLINK_CACHE", str(tmp_path / "probe"))
    name = _fresh_load(xml).name  # the file name a planted module would need
    planted = tmp_path / "shared"
    planted.mkdir()
    (planted / name).write_text("raise SystemExit('planted code ran')\n")
    if kind == "world-writable":
        planted.chmod(0o777)
        cache = planted
    else:
        cache = tmp_path / "link"
        cache.symlink_to(planted)
    monkeypatch.setenv("FTCAP_MAVLINK_CACHE", str(cache))
    path = _fresh_load(xml)  # would raise SystemExit if the planted module ran
    assert path.parent != planted and not path.is_relative_to(cache)
    assert path.parent.stat().st_mode & 0o777 == 0o700  # this process's own mkdtemp


def test_install_writes_a_module_pymavlink_tools_import(tmp_path) -> None:
    written = mavlink_dialect.install(tmp_path / "v20")
    assert sorted(p.relative_to(tmp_path).as_posix() for p in written) == [
        "v10/ftcap.py",
        "v20/ftcap.py",
        "v20/ftcap.xml",
    ]
    spec = importlib.util.spec_from_file_location("ftcap_installed", tmp_path / "v20/ftcap.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.MAVLINK_MSG_ID_FTCAP_STATUS == 52801


def test_installed_dialect_lets_mavlogdump_decode_our_messages(tmp_path) -> None:
    """The documented command, then pymavlink's own mavlogdump.py --dialect ftcap."""
    out = subprocess.run(
        [sys.executable, "-m", "bridges.mavlink.dialect", "--install"],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    assert "dialects/v20/ftcap.py" in out.stdout
    mav = DIALECT.MAVLink(None, srcSystem=1, srcComponent=191)
    frame = DIALECT.MAVLink_ftcap_thrust_message(5, [0.25] * 16, 4).pack(mav)
    log = tmp_path / "flight.tlog"
    log.write_bytes(struct.pack(">Q", 1_700_000_000_000_000) + frame)  # tlog: usec + frame
    dump = Path(sys.executable).with_name("mavlogdump.py")
    shown = subprocess.run(
        [sys.executable, str(dump), "--dialect", "ftcap", str(log)],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    assert "FTCAP_THRUST" in shown.stdout and "UNKNOWN" not in shown.stdout


_MAVUTIL_READER = """
import os, sys
from pathlib import Path
import pymavlink.dialects.v10 as v10, pymavlink.dialects.v20 as v20
root = Path(sys.argv[1])
v20.__path__.insert(0, str(root / "v20"))  # the installed dialect, without touching the venv
v10.__path__.insert(0, str(root / "v10"))
from pymavlink import mavutil
log = mavutil.mavlink_connection(sys.argv[2])
msg = log.recv_match()
print(mavutil.current_dialect, msg.get_type(), msg.surge, flush=True)
"""


@pytest.mark.parametrize("mavlink20", [True, False], ids=["MAVLINK20", "no-MAVLINK20"])
def test_installed_dialect_decodes_a_log_with_mavlink_dialect_set(tmp_path, mavlink20) -> None:
    # Issue 22: `MAVLINK_DIALECT=ftcap` (docs/hil.md) raised in mavutil's import unless
    # MAVLINK20 was also set: mavutil looks in dialects/v10 first, where nothing was installed.
    written = mavlink_dialect.install(tmp_path / "v20")
    assert [p.relative_to(tmp_path).as_posix() for p in written] == [
        "v20/ftcap.py",
        "v20/ftcap.xml",
        "v10/ftcap.py",
    ]
    mav = DIALECT.MAVLink(None, srcSystem=1, srcComponent=191)
    frame = DIALECT.MAVLink_wrench_setpoint_message(1, 1, 191, 1.5, -2.0, 3.25).pack(mav)
    tlog = tmp_path / "flight.tlog"
    tlog.write_bytes(struct.pack(">Q", 1_700_000_000_000_000) + bytes(frame))
    env = {k: v for k, v in os.environ.items() if not k.startswith("MAVLINK")}
    env["MAVLINK_DIALECT"] = "ftcap"
    if mavlink20:
        env["MAVLINK20"] = "1"
    out = subprocess.run(
        [sys.executable, "-c", _MAVUTIL_READER, str(tmp_path), str(tlog)],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["ftcap", "WRENCH_SETPOINT", "1.5"]
