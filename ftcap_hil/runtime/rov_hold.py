"""An ROV holding station in 6 DOF with one thruster dead: the allocation told, or not.

The offline loop of an underwater vehicle, as far as the product takes it today: the 6-DOF
rigid body (``core/models/vehicle6dof.py``) in a current, the nominal hold controller
(``core/models/controller6dof.py``) and the allocator (the same QP as on the surface, in 6
axes), at a fixed control period. A thruster dies at ``fault_s``: from then on it gives no
thrust. The allocator either knows it from the fault's onset (``oracle``: delta_hat = 0 for
that thruster, as once the fault is isolated) or never does (``cap``: delta_hat = 1 for all,
the fault-unaware baseline); ``healthy`` has no fault. Thrusters are ideal (no lag, no
drives' physics yet); the estimator that would isolate the fault is not in this loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ftcap_hil.config.underwater import UnderwaterVehicle
from ftcap_hil.core.allocation.allocator import Allocator, AllocatorConfig
from ftcap_hil.core.estimation.config import wrench_scale
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.controller6dof import HoldController6DOF

MODES = ("healthy", "oracle", "cap")


@dataclass(frozen=True)
class HoldResult:
    """What a pilot sees of one hold after the fault's onset (SI, degrees for angles)."""

    mode: str
    dead: str | None
    depth_dev_max_m: float  # largest |depth - target|
    horizontal_dev_max_m: float  # largest horizontal distance from the target
    roll_pitch_max_deg: float  # largest |roll| or |pitch|
    heading_dev_max_deg: float
    unmet_rms: float  # RMS of the unallocated wrench over the axis scales


def hold(
    vehicle: UnderwaterVehicle,
    mode: str,
    dead: int | None = None,
    *,
    seconds: float = 60.0,
    fault_s: float = 30.0,
    period_s: float = 0.05,
    substeps: int = 5,
    depth_m: float = 5.0,
    current_ned: tuple[float, float, float] = (0.2, 0.0, 0.0),
) -> HoldResult:
    """One hold at ``depth_m`` (heading north, level) in ``current_ned`` (m/s) with thruster
    ``dead`` (index) dying at ``fault_s``; ``mode`` one of :data:`MODES`."""
    if mode not in MODES:
        raise ValueError(f"rov hold: mode is one of {MODES}, got {mode!r}")
    if (mode == "healthy") != (dead is None):
        raise ValueError("rov hold: a dead thruster with 'oracle' or 'cap', none with 'healthy'")
    ths, B, body = vehicle.thrusters, vehicle.B, vehicle.body
    scale = wrench_scale(B, ths.u_min, ths.u_max)
    alloc = Allocator(B, ths, period_s, scale, AllocatorConfig())
    ctrl = HoldController6DOF(body)
    target = np.array([0.0, 0.0, depth_m, 0.0, 0.0, 0.0])
    x = np.concatenate([target, np.zeros(6)])
    current = np.array(current_ned, dtype=np.float64)
    u = np.zeros(ths.m)
    alive = np.ones(ths.m)
    delta_hat = np.ones(ths.m)
    dev = {"depth": 0.0, "horizontal": 0.0, "attitude": 0.0, "heading": 0.0}
    unmet: list[FloatArray] = []
    h = period_s / substeps
    for k in range(round(seconds / period_s)):
        t = k * period_s
        if dead is not None and t >= fault_s:
            alive[dead] = 0.0
            if mode == "oracle":
                delta_hat[dead] = 0.0
        tau_d = ctrl(x[:6], x[6:], target, period_s)
        res = alloc.allocate(tau_d, delta_hat, np.zeros(6), u)
        u = res.u
        tau = B @ (alive * u)
        for _ in range(substeps):
            x = body.step_rk4(x, tau, h, current)
        if t >= fault_s:
            unmet.append((tau_d - tau) / scale)
            dev["depth"] = max(dev["depth"], abs(x[2] - depth_m))
            dev["horizontal"] = max(dev["horizontal"], math.hypot(x[0], x[1]))
            dev["attitude"] = max(dev["attitude"], abs(x[3]), abs(x[4]))
            dev["heading"] = max(dev["heading"], abs(x[5]))
    return HoldResult(
        mode=mode,
        dead=None if dead is None else ths.names[dead],
        depth_dev_max_m=dev["depth"],
        horizontal_dev_max_m=dev["horizontal"],
        roll_pitch_max_deg=math.degrees(dev["attitude"]),
        heading_dev_max_deg=math.degrees(dev["heading"]),
        unmet_rms=float(np.sqrt(np.mean(np.square(unmet)))) if unmet else 0.0,
    )
