"""The ground station's record of a flight, in the offline simulator's columns."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.plants import wrap_angle
from ftcap_hil.core.scenario import Scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.report.records import RunRecord, column_names


class FlightRecorder:
    """The ground station's record of a flight, in ``report.column_names`` order.

    Per cycle: mission time t (s), the pose from ODOMETRY (psi unwrapped), the reference,
    the wrench sent, the allocator's status (``status``: delta_hat, f_hat, degraded) and
    ACTUATOR_OUTPUT_STATUS (``u``, N) as last received (None: not yet: NaN), and the true
    faults from the mission's schedule: v_ach = B (delta u + f), bf_hat = B f_hat.
    innovation, window_len, probing and solve_us are not on MAVLink: NaN.
    """

    def __init__(self, scenario: Scenario) -> None:
        self.sc = scenario
        self.names = column_names(self.sc)
        self.rows: list[FloatArray] = []
        self._psi: float | None = None

    def _unwrapped(self, psi: float) -> float:
        # ODOMETRY carries yaw in (-pi, pi]; the offline record's psi is continuous
        self._psi = psi if self._psi is None else self._psi + float(wrap_angle(psi - self._psi))
        return self._psi

    def add(
        self, t: float, x: FloatArray, ref: FloatArray, v_dem: FloatArray, status: Any, u: Any
    ) -> None:
        sc, m = self.sc, self.sc.thrusters.m
        truth = sc.faults.at(t)
        nan_m = np.full(m, math.nan)
        u_arr = np.asarray(u, dtype=np.float64) if u is not None and len(u) == m else nan_m
        produced = truth.delta * u_arr + truth.f
        dh = status.delta_hat if status is not None and len(status.delta_hat) == m else nan_m
        fh = status.f_hat if status is not None and len(status.f_hat) == m else nan_m
        degraded = 0.0 if status is None else float(status.degraded)
        pose = np.array([x[0], x[1], self._unwrapped(float(x[2])), *x[3:]])
        row = np.concatenate(
            [
                [t],
                pose,
                ref,
                v_dem,
                sc.B @ produced,
                u_arr,
                produced,
                truth.delta,
                truth.f,
                dh,
                fh,
                sc.B @ fh,
                [math.nan, math.nan, degraded, math.nan, math.nan],
            ]
        )
        assert row.size == len(self.names)
        self.rows.append(row)

    def finish(self, mode: str, period_s: float, **meta: Any) -> RunRecord:
        """The record; a flight cut short gets a scenario that ends where the flight did."""
        data = np.vstack(self.rows) if self.rows else np.zeros((0, len(self.names)))
        sc = self.sc.with_mode(Mode(mode)) if mode in {m.value for m in Mode} else self.sc
        if self.rows and data[-1, 0] + period_s < sc.duration_s:
            sc = replace(sc, duration_s=float(data[-1, 0] + period_s))
        return RunRecord(sc, mode, {n: data[:, i] for i, n in enumerate(self.names)}, meta)
