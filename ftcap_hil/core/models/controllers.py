"""Nominal (fault-unaware) controllers of the paper: they produce the virtual input v."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.plants import wrap_angle


@dataclass(frozen=True)
class StateFeedback:
    """Section 4.1: v = K x + K_r r, K_r = ((I - A - B_v K)^-1 B_v)^-1 (scalar plant)."""

    gain: float = -0.6
    a: float = 1.2
    b_v: float = 1.0

    @property
    def k_r(self) -> float:
        """Reference gain K_r (unit DC gain from r to x)."""
        return 1.0 / (self.b_v / (1.0 - self.a - self.b_v * self.gain))

    def __call__(self, x: FloatArray, ref: FloatArray) -> FloatArray:
        """v (1,) from the state x (1,) and the reference r (1,)."""
        return np.array([self.gain * x[0] + self.k_r * ref[0]])


@dataclass(frozen=True)
class PoseController:
    """Eq. (24): v = K_p [R(psi)^T K_eta (eta_d - eta) - nu]; the heading error is wrapped
    to (-pi, pi] so that a reference of pi and a heading of -pi are the same.

    ``kp`` and ``k_eta`` are the paper's scalars or one gain per axis (surge, sway, yaw);
    :meth:`for_vessel` sizes them to a vessel's inertia for a natural period and damping."""

    kp: float | tuple[float, float, float] = 0.75
    k_eta: float | tuple[float, float, float] = 0.63

    @classmethod
    def for_vessel(
        cls, inertia: FloatArray, period_s: float, damping: float = 0.9
    ) -> PoseController:
        """Gains that make each axis of a vessel with diagonal inertia ``inertia`` (3,)
        (kg, kg, kg m^2: added mass included) a second-order system of natural period
        ``period_s`` (s) and damping ratio ``damping``: M e'' + kp e' + kp k_eta e = 0, so
        kp = 2 zeta omega M and k_eta = omega / (2 zeta)."""
        if not (period_s > 0 and damping > 0):
            raise ValueError(
                f"controller: need period_s > 0 and damping > 0, got {period_s}, {damping}"
            )
        omega = 2.0 * math.pi / period_s
        m = np.asarray(inertia, dtype=np.float64)
        kp = 2.0 * damping * omega * m
        k_eta = omega / (2.0 * damping)
        return cls(kp=(float(kp[0]), float(kp[1]), float(kp[2])), k_eta=(k_eta,) * 3)

    def __call__(self, x: FloatArray, ref: FloatArray) -> FloatArray:
        """v (3,) body wrench [X (N), Y (N), N (N*m)] from x = [eta (3, NED), nu (3, body)]
        and the pose reference eta_d (3,) = [north (m), east (m), psi (rad)]."""
        eta, nu = x[:3], x[3:6]
        err = np.asarray(ref, dtype=np.float64) - eta
        err[2] = float(wrap_angle(err[2]))
        c, s = math.cos(eta[2]), math.sin(eta[2])
        body = np.array([c * err[0] + s * err[1], -s * err[0] + c * err[1], err[2]])
        out: FloatArray = np.asarray(self.kp) * (np.asarray(self.k_eta) * body - nu)
        return out


def limit_wrench(v: FloatArray, limit: tuple[float, float, float]) -> FloatArray:
    """Shrink ``v`` along its direction so that |v_j| <= limit_j (the allocator drops a
    WRENCH_SETPOINT beyond its wrench limit as malformed)."""
    scale = float(np.max(np.abs(v) / np.asarray(limit)))
    return v / scale if scale > 1.0 else v
