"""The ftcap MAVLink dialect: free message ids, pinned wire format, cached generation."""

from __future__ import annotations

import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from bridges.mavlink import dialect as mavlink_dialect
from tests.contract.mavlink_support import DIALECT


def _message_ids(xml: Path) -> dict[int, str]:
    root = ET.parse(xml).getroot()
    return {int(m.get("id", -1)): m.get("name", "") for m in root.iter("message")}


def test_our_ids_are_in_our_range_and_free_in_every_bundled_dialect() -> None:
    ours = _message_ids(mavlink_dialect.XML)
    assert set(ours.values()) == {"WRENCH_SETPOINT", "FTCAP_STATUS", "FTCAP_ESC_STATUS"}
    assert all(i in mavlink_dialect.MESSAGE_IDS for i in ours)
    bundled = sorted(mavlink_dialect.pymavlink_definitions_dir().glob("*.xml"))
    assert any(p.name == "all.xml" for p in bundled)
    for xml in bundled:
        clash = set(ours) & set(_message_ids(xml))
        assert not clash, f"{xml.name} also uses message ids {sorted(clash)}"


def test_wire_format_is_pinned() -> None:
    # crc_extra hashes names and types of the fields: a change here breaks every peer
    # built from the old XML, so it must be deliberate (update these numbers with it).
    assert DIALECT.MAVLINK_MSG_ID_WRENCH_SETPOINT == 52800
    assert DIALECT.MAVLink_wrench_setpoint_message.crc_extra == 232
    assert DIALECT.MAVLINK_MSG_ID_FTCAP_STATUS == 52801
    assert DIALECT.MAVLink_ftcap_status_message.crc_extra == 25
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
