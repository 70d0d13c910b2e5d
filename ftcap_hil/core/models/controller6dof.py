"""A nominal (fault-unaware) station-keeping controller for a 6-DOF underwater vehicle.

What an ROV autopilot's hold modes do (ArduSub's depth and heading hold, PX4's UUV position
control), in one law: the restoring wrench the model predicts, fed forward, plus a PID per
NED translation axis rotated into the body frame and a PD per Euler angle::

    tau = g_hat(eta) + [R^T (k_p e_p + k_i int e_p) - k_d v;  k_a e_a - k_w omega]
    e_p = p_d - p (NED),  e_a = [phi_d - phi, theta_d - theta, wrap(psi_d - psi)]

Gains are sized per axis from the vehicle's inertia (added mass included) for a natural
period and damping ratio, as :meth:`PoseController.for_vessel` does on the surface; the
integral (depth holds it against an unknown net buoyancy) is limited to ``integral_limit``
of the vehicle's weight so that a saturated axis does not wind up.
"""

from __future__ import annotations

import math

import numpy as np

from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.plants import wrap_angle
from ftcap_hil.core.models.vehicle6dof import Vehicle6DOF, rotation


class HoldController6DOF:
    """Station keeping in 6 DOF (module docstring); one instance per run (it integrates)."""

    def __init__(
        self,
        model: Vehicle6DOF,
        period_s: float = 6.0,
        damping: float = 0.9,
        integral_period_s: float = 30.0,
        integral_limit: float = 0.2,
    ) -> None:
        if not (period_s > 0 and damping > 0 and integral_period_s > 0):
            raise ValueError("controller: periods and damping must be > 0")
        omega = 2.0 * math.pi / period_s
        m = np.diag(model.mass_matrix)
        self._model = model
        self._kp = m * omega**2  # (6,): translation N/m, rotation N m/rad
        self._kd = 2.0 * damping * omega * m
        self._ki = self._kp[:3] * (2.0 * math.pi / integral_period_s)
        self._i_limit = integral_limit * model.weight_n
        self._integral = np.zeros(3)

    def __call__(
        self, eta: FloatArray, nu: FloatArray, eta_d: FloatArray, dt_s: float
    ) -> FloatArray:
        """The demanded body wrench tau (6,) for the pose ``eta`` (6,), body velocity
        ``nu`` (6,) and target pose ``eta_d`` (6,); ``dt_s`` since the last call."""
        R = rotation(float(eta[3]), float(eta[4]), float(eta[5]))
        e_p = eta_d[:3] - eta[:3]
        self._integral = np.clip(
            self._integral + e_p * dt_s, -self._i_limit / self._ki, self._i_limit / self._ki
        )
        e_a = eta_d[3:] - eta[3:]
        e_a[2] = wrap_angle(float(e_a[2]))
        force_ned = self._kp[:3] * e_p + self._ki * self._integral
        force = R.T @ force_ned - self._kd[:3] * nu[:3]
        moment = self._kp[3:] * e_a - self._kd[3:] * nu[3:]
        tau: FloatArray = self._model.restoring(eta) + np.concatenate([force, moment])
        return tau
