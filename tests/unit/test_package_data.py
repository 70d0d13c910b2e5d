"""Every package-data pattern in pyproject.toml names files that exist: a wrong one leaves
them out of the wheel (the Docker image) without a word, as `bridges/mavlink_dialect/*.xml`
did for the MAVLink dialect the image generates its module from."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_every_package_data_pattern_matches_files() -> None:
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    data = cfg["tool"]["setuptools"]["package-data"]
    assert data, "no package-data"
    for package, patterns in data.items():
        for pattern in patterns:
            assert list((ROOT / package).glob(pattern)), f"{package}: {pattern} matches nothing"


def test_the_dialect_xml_is_package_data() -> None:
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    patterns = cfg["tool"]["setuptools"]["package-data"]["bridges"]
    assert any((ROOT / "bridges" / "mavlink" / "dialect" / "ftcap.xml").match(f"*/{p}")
               for p in patterns), patterns  # fmt: skip
