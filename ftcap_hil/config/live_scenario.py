"""A realistic scenario flown live (``ftcap-hil sim --scenario``, ``ftcap-hil allocator
--scenario``): both processes read the same document, so nobody writes the vessel twice.

The vessel process steps the scenario's truth (:class:`~sim.truth.TruthConfig`) with its
``[[fault]]`` schedule on sim time; the allocator is told what the offline simulator tells
its core (``config/realistic.py``: the mismatched model and geometry, the limits, the data
sheets of the drives, the sensor's noise, the thrusters' lag, the sea-state model). The
configuration file's ``[vessel]`` and ``[plant]`` are still read (strictly) but not used, and
a ``[can] esc_node_ids`` list that does not fit the scenario's thrusters gives way to the
default one ESC node per thruster (20, 21, ...).

A setpoint's bound (``[mavlink]`` / ``[zenoh]`` ``wrench_limit`` of the allocator, ``[gcs]
wrench_limit`` of the ground station: components beyond are garbage, dropped or shrunk) is
written for the file's vessel, 1000 N a component for the paper's; the scenario's vessel
needs its own: at least :data:`SETPOINT_HEADROOM` times what all its thrusters give together
on each axis (:func:`wrench_bound`). A supply vessel's station keeping asks for up to 0.5 MN
of sway, which the 1000 N bound shrank to nothing (it drifted 7 m in a minute live).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.estimation.config import wrench_scale
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


# A controller's demand is rarely over what the thrusters can give; a large reference step
# asks for more (CyberShip II's transit: 25 times its sway capacity). Garbage is far beyond.
SETPOINT_HEADROOM = 100.0


def wrench_bound(sc: Scenario, given: tuple[float, ...]) -> tuple[float, float, float]:
    """Per component the larger of ``given`` (a file's bound) and SETPOINT_HEADROOM times
    the scenario vessel's whole capacity on that axis (:func:`wrench_scale`, the estimator's
    axis scale; module docstring)."""
    th = sc.thrusters
    capacity = wrench_scale(sc.B, th.u_min, th.u_max)
    x, y, n = (
        max(float(g), SETPOINT_HEADROOM * float(c)) for g, c in zip(given, capacity, strict=True)
    )
    return x, y, n
