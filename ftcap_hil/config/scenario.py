"""Scenario files (TOML): plant, thrusters, reference, faults, controller, allocator settings.

The format is documented in ``docs/scenarios.md``; shipped files live in
``ftcap_hil/data/scenarios``. Every error names the offending key and value.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.config.fault_keys import fault_event
from ftcap_hil.config.realistic import is_realistic, parse_realistic
from ftcap_hil.config.tables import dataclass_from_table, get, number, vector
from ftcap_hil.config.toml import read_toml, shipped_names
from ftcap_hil.config.vessel import plant_from_tables
from ftcap_hil.core.allocator import AllocatorConfig
from ftcap_hil.core.controllers import PoseController, StateFeedback
from ftcap_hil.core.cycle import CoreConfig
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.estimator import EstimatorConfig
from ftcap_hil.core.excitation import ExcitationConfig
from ftcap_hil.core.faults import FaultSchedule
from ftcap_hil.core.plants import LinearPlant
from ftcap_hil.core.scenario import Scenario, Segment
from ftcap_hil.core.status import Mode


def _faults(entries: list[dict[str, Any]], m: int, where: str) -> FaultSchedule:
    events = []
    for i, ev in enumerate(entries):
        w = f"{where}.fault[{i}]"
        thr = ev.get("thruster")
        if thr is not None and not (isinstance(thr, int) and 1 <= thr <= m):
            raise ConfigError(f"{w}.thruster: expected 1..{m} (1-based), got {thr!r}")
        size = 1 if thr is not None else m
        delta = vector(ev["delta"], f"{w}.delta", size) if "delta" in ev else None
        bias = vector(ev["bias"], f"{w}.bias", size) if "bias" in ev else None
        if delta is not None and np.any((delta < 0) | (delta > 1)):
            raise ConfigError(f"{w}.delta: must lie in [0, 1], got {ev['delta']!r}")
        events.append(
            fault_event(
                ev,
                w,
                number(ev, "from", w),
                number(ev, "until", w) if "until" in ev else math.inf,
                None if thr is None else thr - 1,
                None if delta is None else (delta[0] if thr is not None else delta),
                None if bias is None else (bias[0] if thr is not None else bias),
            )
        )
    return FaultSchedule(m, tuple(events))


def parse_scenario(data: dict[str, Any], where: str = "scenario") -> Scenario:
    if is_realistic(data):
        return parse_realistic(data, where)
    head = get(data, "scenario", where)
    plant, ths, B = plant_from_tables(data, where)
    k = B.shape[0]
    ctl_t = data.get("controller", {})
    if isinstance(plant, LinearPlant):
        controller: StateFeedback | PoseController = StateFeedback(
            gain=number(ctl_t, "K", f"{where}.controller", -0.6), a=plant.a, b_v=plant.b_v
        )
        ref_len, x_len, unit = 1, 1, "step"
    else:
        controller = PoseController(
            kp=number(ctl_t, "kp", f"{where}.controller", 0.75),
            k_eta=number(ctl_t, "k_eta", f"{where}.controller", 0.63),
        )
        ref_len, x_len, unit = 3, 6, "s"
    refs = get(data, "reference", where)
    reference = tuple(
        Segment(
            number(r, "from", f"{where}.reference[{i}]"),
            vector(
                get(r, "value", f"{where}.reference[{i}]"),
                f"{where}.reference[{i}].value",
                ref_len,
            ),
        )
        for i, r in enumerate(refs)
    )
    mode_name = head.get("mode", "ftcap")
    try:
        mode = Mode(mode_name)
    except ValueError:
        raise ConfigError(
            f"{where}.scenario.mode: {mode_name!r} not one of {[m.value for m in Mode]}"
        ) from None
    core = CoreConfig(
        mode=mode,
        estimator=dataclass_from_table(
            EstimatorConfig,
            # a discrete-time plant has no sample straddling an onset (faults act per step)
            {"evict_straddling": not isinstance(plant, LinearPlant), **data.get("estimator", {})},
            f"{where}.estimator",
        ),
        allocator=dataclass_from_table(
            AllocatorConfig, data.get("allocator", {}), f"{where}.allocator"
        ),
        excitation=dataclass_from_table(
            ExcitationConfig, data.get("excitation", {}), f"{where}.excitation"
        ),
    )
    noise = data.get("noise", {}).get("state_std")
    integrator = head.get("integrator", "euler")
    if integrator not in ("euler", "rk4"):
        raise ConfigError(
            f"{where}.scenario.integrator: expected 'euler' or 'rk4', got {integrator!r}"
        )
    x0 = vector(head.get("x0", [0.0] * x_len), f"{where}.scenario.x0", x_len)
    dt = number(head, "dt", f"{where}.scenario", 1.0 if unit == "step" else math.nan)
    if not dt > 0:
        raise ConfigError(f"{where}.scenario.dt: must be > 0, got {dt}")
    sc = Scenario(
        name=str(head.get("name", where)),
        description=str(head.get("description", "")),
        plant=plant,
        thrusters=ths,
        B=B,
        dt_s=dt,
        duration_s=number(head, "duration", f"{where}.scenario"),
        x0=x0,
        controller=controller,
        reference=reference,
        faults=_faults(data.get("fault", []), ths.m, where),
        core=core,
        integrator=integrator,
        rk4_substeps=int(head.get("rk4_substeps", 8)),
        noise_std=np.zeros(x_len)
        if noise is None
        else vector(noise, f"{where}.noise.state_std", x_len),
        seed=int(head.get("seed", 0)),
        time_unit=unit,
    )
    if k != ref_len:
        raise ConfigError(f"{where}: B has {k} rows but the plant has {ref_len} virtual inputs")
    return sc


SHIPPED = "ftcap_hil.data.scenarios"


def shipped_scenarios() -> list[str]:
    """Names of the scenarios shipped in ``ftcap_hil/data/scenarios``."""
    return shipped_names(SHIPPED)


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A path to a TOML file, or the name of a shipped scenario (``paper-4.2-ex1``)."""
    doc = read_toml(name_or_path, SHIPPED, what="scenario")
    return parse_scenario(doc.data, doc.source)
