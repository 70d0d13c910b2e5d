"""Scenario files (TOML): plant, thrusters, reference, faults, controller, allocator settings.

The format is documented in ``docs/scenarios.md``; shipped files live in
``ftcap_hil/data/scenarios``. A file whose ``[plant] kind = "preset"`` is a realistic
scenario (:mod:`ftcap_hil.config.realistic`); any other is read by
:func:`~ftcap_hil.config.scenario_tables.scenario_from`. Either way every error names the
file, the table and the key, and an unknown key or table is an error.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ftcap_hil.config.realistic import anchor_preset, is_realistic, parse_realistic
from ftcap_hil.config.scenario_tables import scenario_from
from ftcap_hil.config.tables import Table
from ftcap_hil.config.toml import read_toml, shipped_names
from ftcap_hil.core.scenario import Scenario

SHIPPED = "ftcap_hil.data.scenarios"


def parse_scenario(
    data: Mapping[str, Any], file: str = "scenario", base: Path | None = None
) -> Scenario:
    """A scenario from a parsed TOML document (``file`` names it in messages); one whose
    ``[plant] kind = "preset"`` is a realistic scenario (``config/realistic.py``), its
    relative ``[plant] preset`` path read from ``base``, the file's folder (None: the
    working directory)."""
    if is_realistic(dict(data)):
        return parse_realistic(anchor_preset(data, base), file)
    with Table(data, file) as root:
        return scenario_from(root)


def shipped_scenarios() -> list[str]:
    """Names of the scenarios shipped in ``ftcap_hil/data/scenarios``."""
    return shipped_names(SHIPPED)


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A path to a TOML file, or the name of a shipped scenario (``paper-4.2-ex1``)."""
    doc = read_toml(name_or_path, SHIPPED, what="scenario")
    return parse_scenario(doc.data, doc.source, doc.base)
