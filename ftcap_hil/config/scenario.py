"""Scenario files (TOML): plant, thrusters, reference, faults, controller, allocator settings.

The format is documented in ``docs/scenarios.md``; shipped files live in
``ftcap_hil/data/scenarios``. Read with :class:`~ftcap_hil.config.tables.Table`: every error
names the file, the table and the key, and an unknown key or table is an error.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ftcap_hil.config.fault_keys import fault_schedule_from
from ftcap_hil.config.realistic import is_realistic, parse_realistic
from ftcap_hil.config.table_dataclass import read_dataclass
from ftcap_hil.config.tables import Table
from ftcap_hil.config.toml import read_toml, shipped_names
from ftcap_hil.config.vessel import plant_from
from ftcap_hil.core.allocation.allocator import AllocatorConfig
from ftcap_hil.core.allocation.excitation import ExcitationConfig
from ftcap_hil.core.allocation.qp import available_backends
from ftcap_hil.core.cycle import CoreConfig
from ftcap_hil.core.estimation.config import EstimatorConfig
from ftcap_hil.core.models.controllers import PoseController, StateFeedback
from ftcap_hil.core.models.plants import LinearPlant
from ftcap_hil.core.scenario import Scenario, Segment
from ftcap_hil.core.status import Mode

SHIPPED = "ftcap_hil.data.scenarios"
INTEGRATORS = ("euler", "rk4")
REPLACEABLE = ("controller", "reference", "fault")  # tables a mission may give instead


def core_config_from(root: Table, mode: Mode, k: int, evict_straddling: bool = True) -> CoreConfig:
    """``[estimator]``, ``[allocator]``, ``[excitation]``: the core's tunables (every key of
    EstimatorConfig, AllocatorConfig, ExcitationConfig; the backend among those installed;
    ``measurement_std`` one value per dynamic state, k of them, or for a vessel 2 k: the
    pose's and the velocities', and the filter tracks the pose too)."""
    root.renamed("allocation", "allocator")
    est_t = root.table("estimator")
    estimator = read_dataclass(
        est_t, EstimatorConfig, defaults={"evict_straddling": evict_straddling}
    )
    std = estimator.measurement_std
    sizes = (k, 2 * k) if k == 3 else (k,)
    if std is not None and (len(std) not in sizes or min(std) < 0.0):
        want = " or ".join(str(n) for n in sizes)
        raise est_t.error("measurement_std", f"expected {want} numbers >= 0, got {list(std)}")
    ws = estimator.wave_force_std
    if ws is not None and (len(ws) != k or min(ws) <= 0.0):
        raise est_t.error("wave_force_std", f"expected {k} numbers > 0, got {list(ws)}")
    return CoreConfig(
        mode=mode,
        estimator=estimator,
        allocator=read_dataclass(
            root.table("allocator"), AllocatorConfig, choices={"backend": available_backends()}
        ),
        excitation=read_dataclass(root.table("excitation"), ExcitationConfig),
    )


def _controller(t: Table, plant: Any) -> StateFeedback | PoseController:
    if isinstance(plant, LinearPlant):
        return StateFeedback(gain=t.number("K", -0.6), a=plant.a, b_v=plant.b_v)
    return PoseController(kp=t.number("kp", 0.75), k_eta=t.number("k_eta", 0.63))


def scenario_from(root: Table, mission: Table | None = None) -> Scenario:
    """A scenario from the top level of its file. ``mission``: the top level of a mission
    file whose ``[controller]``, ``[[reference]]``, ``[[fault]]`` replace the scenario's."""
    own = {k: mission if mission is not None and mission.has(k) else root for k in REPLACEABLE}
    root.allow(*REPLACEABLE)
    head = root.table("scenario", required=True)
    plant, ths, B = plant_from(root)
    linear = isinstance(plant, LinearPlant)
    ref_len, x_len, unit = (1, 1, "step") if linear else (3, 6, "s")
    if B.shape[0] != ref_len:
        raise root.error(None, f"B has {B.shape[0]} rows but the plant has {ref_len} inputs")
    reference = tuple(
        Segment(r.number("from"), r.vector("value", ref_len))
        for r in own["reference"].tables("reference", required=True)
    )
    mode = head.enum("mode", Mode, Mode.FTCAP)
    # a discrete-time plant has no sample straddling an onset (faults act per step)
    core = core_config_from(root, mode, ref_len, evict_straddling=not linear)
    noise = root.table("noise").vector("state_std", x_len, [0.0] * x_len, lo=0.0)
    return Scenario(
        name=head.string("name", root.file),
        description=head.string("description", ""),
        plant=plant,
        thrusters=ths,
        B=B,
        dt_s=head.number("dt", 1.0, positive=True) if linear else head.number("dt", positive=True),
        duration_s=head.number("duration", positive=True),
        x0=head.vector("x0", x_len, [0.0] * x_len),
        controller=_controller(own["controller"].table("controller"), plant),
        reference=reference,
        faults=fault_schedule_from(own["fault"].tables("fault"), ths.m),
        core=core,
        integrator=head.choice("integrator", INTEGRATORS, "euler"),
        rk4_substeps=head.integer("rk4_substeps", 8, lo=1),
        noise_std=noise,
        seed=head.integer("seed", 0, lo=0),
        time_unit=unit,
    )


def parse_scenario(data: Mapping[str, Any], file: str = "scenario") -> Scenario:
    """A scenario from a parsed TOML document (``file`` names it in messages); one whose
    ``[plant] kind = "preset"`` is a realistic scenario (``config/realistic.py``)."""
    if is_realistic(dict(data)):
        return parse_realistic(dict(data), file)
    with Table(data, file) as root:
        return scenario_from(root)


def shipped_scenarios() -> list[str]:
    """Names of the scenarios shipped in ``ftcap_hil/data/scenarios``."""
    return shipped_names(SHIPPED)


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A path to a TOML file, or the name of a shipped scenario (``paper-4.2-ex1``)."""
    doc = read_toml(name_or_path, SHIPPED, what="scenario")
    return parse_scenario(doc.data, doc.source)
