"""A closed-loop scenario: plant, thrusters, reference, true faults, controller, allocator.

The type only; ``ftcap_hil.config.scenario`` reads it from TOML (docs/scenarios.md).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ftcap_hil.core.cycle import CoreConfig
from ftcap_hil.core.effectiveness.geometry import ThrusterSet
from ftcap_hil.core.errors import require_member
from ftcap_hil.core.estimation.shaft import DriveModel
from ftcap_hil.core.faults import FaultSchedule
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.controllers import PoseController, StateFeedback
from ftcap_hil.core.models.vessel3dof import PlantModel
from ftcap_hil.core.status import Mode


class Integrator(enum.Enum):
    """How the offline truth integrates a vessel plant over one step."""

    EULER = "euler"  # the plant's own step: the allocator's discrete model, exactly
    RK4 = "rk4"  # ``rk4_substeps`` RK4 substeps with tau held


class TimeUnit(enum.Enum):
    """What a scenario's times count (the string is what results.json says)."""

    SECOND = "s"
    STEP = "step"  # the discrete linear plant of section 4.1


@dataclass(frozen=True)
class Segment:
    """A value that holds from ``start`` (inclusive) until the next segment."""

    start: float
    value: FloatArray


@dataclass(frozen=True)
class Scenario:
    """One offline closed-loop run (docs/scenarios.md): the plant (linear, state x (1,), or
    the surface vessel, x = [eta (3, NED), nu (3, body)]), its thrusters and B (k, m), the
    step ``dt_s`` and ``duration_s`` (s; steps when ``time_unit`` is ``STEP``), the initial
    state ``x0``, the nominal controller and its piecewise-constant reference, the true
    faults, the allocator core's settings, the truth's integrator and the state noise
    (``noise_std``, per state component, with ``seed``).
    """

    name: str
    description: str
    plant: PlantModel
    thrusters: ThrusterSet
    B: FloatArray  # (k, m)
    dt_s: float
    duration_s: float
    x0: FloatArray
    controller: StateFeedback | PoseController
    reference: tuple[Segment, ...]
    faults: FaultSchedule
    core: CoreConfig
    integrator: Integrator = Integrator.EULER  # the truth's (a paper-world scenario)
    rk4_substeps: int = 8
    noise_std: FloatArray = field(default_factory=lambda: np.zeros(0))
    seed: int = 0
    time_unit: TimeUnit = TimeUnit.SECOND
    # The vessel's truth when it is not the allocator's plant: a sim.truth.TruthConfig
    # (realistic scenarios, config/realistic.py); None: the paper's world, where the truth
    # is ``plant`` itself integrated by ``integrator``.
    truth: Any = None
    length_m: float = math.nan  # the vessel's length overall (m), NaN: not stated
    # Estimation samples this far apart (s), a multiple of dt_s (None: every step): over
    # several wave periods the wave-frequency motion averages out of the evidence.
    estimation_period_s: float | None = None
    # The drives as their data sheets give them (core/estimation/shaft.py), one per thruster:
    # the allocator then judges each thruster by its own telemetry (None: motion only).
    drives: tuple[DriveModel, ...] | None = None

    def __post_init__(self) -> None:
        require_member("integrator", self.integrator, Integrator)
        require_member("time_unit", self.time_unit, TimeUnit)

    @property
    def steps(self) -> int:
        """Number of steps of the run."""
        return int(round(self.duration_s / self.dt_s))

    def reference_at(self, t: float) -> FloatArray:
        """The reference in force at ``t``: the last segment that started at or before it."""
        value = self.reference[0].value
        for seg in self.reference:
            if seg.start <= t:
                value = seg.value
        return value

    def phases(self) -> list[tuple[float, float]]:
        """Fault phases [start, end) covering the run, split at every fault change."""
        cuts = [t for t in self.faults.change_times() if 0.0 < t < self.duration_s]
        bounds = [0.0, *cuts, self.duration_s]
        return list(zip(bounds[:-1], bounds[1:], strict=True))

    def with_mode(self, mode: Mode) -> Scenario:
        """The same scenario with the allocator core in ``mode``."""
        return replace(self, core=replace(self.core, mode=mode))
