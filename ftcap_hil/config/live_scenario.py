"""A realistic scenario flown live (``ftcap-hil sim --scenario``, ``ftcap-hil allocator
--scenario``): both processes read the same document, so nobody writes the vessel twice.

The vessel process steps the scenario's truth (:class:`~sim.truth.TruthConfig`) with its
``[[fault]]`` schedule on sim time; the allocator is told what the offline simulator tells
its core (``config/realistic.py``: the mismatched model and geometry, the limits, the data
sheets of the drives, the sensor's noise, the thrusters' lag, the sea-state model). The
configuration file's ``[vessel]`` and ``[plant]`` are still read (strictly) but not used, and
a ``[can] esc_node_ids`` list that does not fit the scenario's thrusters gives way to the
default one ESC node per thruster (20, 21, ...).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.scenario import Scenario

log = logging.getLogger(__name__)


def scenario_for_live(name_or_path: str | Path) -> Scenario:
    """The scenario (file or shipped name; its errors name the file, table and key)."""
    return load_scenario(name_or_path)


def fit_node_ids(data: dict[str, Any], m: int, source: str) -> None:
    """Drop ``[can] esc_node_ids`` from ``data`` (in place) when it does not list ``m``
    nodes: the scenario's vessel replaced the file's (module docstring)."""
    can = data.get("can")
    ids = can.get("esc_node_ids") if isinstance(can, dict) else None
    if isinstance(can, dict) and isinstance(ids, list) and len(ids) != m:
        del can["esc_node_ids"]
        log.info(
            "%s: [can] esc_node_ids lists %d nodes for the file's vessel; the scenario's %d "
            "thrusters take the default ones", source, len(ids), m,
        )  # fmt: skip
