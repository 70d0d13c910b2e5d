"""The ground station's record of a flight, in the offline simulator's columns."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from ftcap_hil.core.estimation.shaft_types import HYPOTHESIS_CODES, Hypothesis
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.plants import wrap_angle
from ftcap_hil.core.scenario import Scenario
from ftcap_hil.core.status import AllocatorStatus, Mode
from ftcap_hil.report.records import Rows, RunRecord

# Columns FTCAP_STATUS / ACTUATOR_OUTPUT_STATUS do not carry: NaN in a flight's record.
NOT_ON_MAVLINK = ("innovation", "window_len", "probing", "solve_us", "dead", "observable")


class FlightRecorder:
    """The ground station's record of a flight, in ``report.column_names`` order.

    Per cycle: mission time t (s), the pose from ODOMETRY (psi unwrapped), the reference,
    the wrench sent, the allocator's status (``status``: delta_hat, f_hat, delta_std, the
    faulty flags, degraded) and ACTUATOR_OUTPUT_STATUS (``u``, N) as last received (None:
    not yet: NaN, ``fallback`` 0), and the true faults from the mission's schedule:
    v_ach = B (delta u + f), bf_hat = B f_hat. The columns of :data:`NOT_ON_MAVLINK` are
    NaN, and so is what a status for another number of thrusters than the mission's vessel
    would put in its columns.
    """

    def __init__(self, scenario: Scenario) -> None:
        self.sc = scenario
        self._rows = Rows(scenario)
        self.names = self._rows.names
        self._psi: float | None = None

    def _unwrapped(self, psi: float) -> float:
        # ODOMETRY carries yaw in (-pi, pi]; the offline record's psi is continuous
        self._psi = psi if self._psi is None else self._psi + float(wrap_angle(psi - self._psi))
        return self._psi

    def add(
        self,
        t: float,
        x: FloatArray,
        ref: FloatArray,
        v_dem: FloatArray,
        status: AllocatorStatus | None,
        u: Any,
    ) -> None:
        sc, m = self.sc, self.sc.thrusters.m
        truth = sc.faults.at(t)
        nan_m = np.full(m, math.nan)
        u_arr = np.asarray(u, dtype=np.float64) if u is not None and len(u) == m else nan_m
        produced = truth.delta * u_arr + truth.f
        pose = np.array([x[0], x[1], self._unwrapped(float(x[2])), *x[3:]])
        fields = _status_fields(status, m)
        self._rows.add(
            t=t,
            state=pose,
            ref=ref,
            v_dem=v_dem,
            v_ach=sc.B @ produced,
            u=u_arr,
            tau=produced,
            delta=truth.delta,
            f=truth.f,
            bf_hat=sc.B @ fields.get("f_hat", nan_m),
            fallback=0.0 if status is None else float(status.degraded),
            **fields,
        )

    def finish(self, mode: str, period_s: float, **meta: Any) -> RunRecord:
        """The record; a flight cut short gets a scenario that ends where the flight did."""
        columns = self._rows.columns()
        sc = self.sc.with_mode(Mode(mode)) if mode in {m.value for m in Mode} else self.sc
        t = columns["t"]
        if t.size and t[-1] + period_s < sc.duration_s:
            sc = replace(sc, duration_s=float(t[-1] + period_s))
        return RunRecord(sc, mode, columns, meta)


def _status_fields(status: AllocatorStatus | None, m: int) -> dict[str, tuple[Any, ...]]:
    """The per-thruster columns a status fills: those it carries for the mission's m."""
    if status is None or status.m != m:
        return {}
    values: dict[str, tuple[Any, ...]] = {
        "delta_hat": status.delta_hat,
        "f_hat": status.f_hat,
        "delta_std": status.delta_std,
        "faulty": status.faulty,
        "drive": tuple(HYPOTHESIS_CODES[Hypothesis(h)] for h in status.hypothesis),
    }
    return {group: v for group, v in values.items() if len(v) == m}
