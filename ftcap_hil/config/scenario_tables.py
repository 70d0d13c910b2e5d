"""The tables every scenario file has: ``[scenario]``, ``[plant]`` and its thrusters,
``[[reference]]``, ``[[fault]]``, ``[controller]``, ``[noise]`` and the core's tunables
(``[estimator]``, ``[allocator]``, ``[excitation]``, which the daemon's file has too).

The format is documented in ``docs/scenarios.md``. Read with
:class:`~ftcap_hil.config.tables.Table`: every error names the file, the table and the key,
and an unknown key or table is an error. A realistic scenario
(:mod:`ftcap_hil.config.realistic`) reads its own tables and hands the rest to
:func:`scenario_from`; :mod:`ftcap_hil.config.scenario` chooses between the two.
"""

from __future__ import annotations

from typing import Any

from ftcap_hil.config.fault_keys import fault_schedule_from
from ftcap_hil.config.table_dataclass import defaults_of, read_dataclass
from ftcap_hil.config.tables import Table
from ftcap_hil.config.vessel import plant_from
from ftcap_hil.core.allocation.allocator import AllocatorConfig
from ftcap_hil.core.allocation.excitation import ExcitationConfig
from ftcap_hil.core.allocation.qp import available_backends
from ftcap_hil.core.cycle import CoreConfig
from ftcap_hil.core.estimation.config import EstimatorConfig
from ftcap_hil.core.models.controllers import PoseController, StateFeedback
from ftcap_hil.core.models.plants import LinearPlant
from ftcap_hil.core.scenario import Integrator, Scenario, Segment, TimeUnit
from ftcap_hil.core.status import Mode

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


def estimation_period_from(head: Table, dt_s: float, default: float | None) -> float | None:
    """``[scenario] estimation_period_s`` (s): a whole number of control periods ``dt_s``."""
    value = head.number("estimation_period_s", default, positive=True)
    if value is None:
        return None
    if value < dt_s or abs(value / dt_s - round(value / dt_s)) > 1e-6:
        raise head.error(
            "estimation_period_s", f"expected a multiple of dt ({dt_s} s), got {value!r}"
        )
    return value


def scenario_from(root: Table, mission: Table | None = None) -> Scenario:
    """A scenario from the top level of its file. ``mission``: the top level of a mission
    file whose ``[controller]``, ``[[reference]]``, ``[[fault]]`` replace the scenario's."""
    own = {k: mission if mission is not None and mission.has(k) else root for k in REPLACEABLE}
    root.allow(*REPLACEABLE)
    head = root.table("scenario", required=True)
    plant, ths, B = plant_from(root)
    linear = isinstance(plant, LinearPlant)
    ref_len, x_len, unit = (1, 1, TimeUnit.STEP) if linear else (3, 6, TimeUnit.SECOND)
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
    base = defaults_of(Scenario)
    dt_s = head.number("dt", 1.0, positive=True) if linear else head.number("dt", positive=True)
    return Scenario(
        name=head.string("name", root.file),
        description=head.string("description", ""),
        plant=plant,
        thrusters=ths,
        B=B,
        dt_s=dt_s,
        duration_s=head.number("duration", positive=True),
        x0=head.vector("x0", x_len, [0.0] * x_len),
        controller=_controller(own["controller"].table("controller"), plant),
        reference=reference,
        faults=fault_schedule_from(own["fault"].tables("fault"), ths.m),
        core=core,
        integrator=head.enum("integrator", Integrator, base["integrator"]),
        rk4_substeps=head.integer("rk4_substeps", base["rk4_substeps"], lo=1),
        noise_std=noise,
        seed=head.integer("seed", base["seed"], lo=0),
        time_unit=unit,
        estimation_period_s=estimation_period_from(head, dt_s, base["estimation_period_s"]),
    )
