"""Plant models of the paper (section 4): what the allocator knows about the vehicle.

Both models give the estimator the same thing: from two consecutive states and the step
length, the generalized force the actuators actually produced over the step,

    w(t) = G^-1 (x(t+1) - A(x(t)))  =  B (Delta u(t) + f(t))          (k,)

which is eq. (5) solved for the actuator term (G = B_v for the linear plant, T_s M^-1 for
the vessel). Estimation then never needs the plant again.

Vessel notation (Fossen): eta = [north, east, psi], nu = [u, v, r], tau = [X, Y, N].
Damping: the paper prints D = diag(beta_u u, beta_v v, beta_r r), which for u < 0 *adds*
energy (D(nu) nu = beta u^2 has the sign of a push). We use D = diag(beta |u|, ...): the
same quadratic drag, dissipative in every direction.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.errors import require_member
from ftcap_hil.core.messages import FloatArray


class Inversion(enum.Enum):
    """How a vessel model's ``measured_wrench`` turns one step into the constant tau that
    made it (the string is the files' spelling)."""

    EULER = "euler"  # drag and Coriolis at nu(t): the paper's discrete model, exactly
    TRAPEZOID = "trapezoid"  # averaged over the step: second order for a continuous truth


@dataclass(frozen=True)
class LinearPlant:
    """x(t+1) = A x(t) + B_v v(t), v = B_u (Delta u + f) (section 4.1; scalar x)."""

    a: float = 1.2
    b_v: float = 1.0
    k: int = 1
    state_labels: tuple[str, ...] = ("x",)

    def step(self, x: FloatArray, tau: FloatArray, dt_s: float) -> FloatArray:
        """x(t+1) (1,) from x(t) (1,) and the actuator term tau (1,); one step (dt_s unused)."""
        return np.array([self.a * x[0] + self.b_v * tau[0]])

    def measured_wrench(self, x_prev: FloatArray, x_now: FloatArray, dt_s: float) -> FloatArray:
        """w (1,) = B_v^-1 (x(t+1) - A x(t)): the actuator term that produced the step."""
        return np.array([(x_now[0] - self.a * x_prev[0]) / self.b_v])


@dataclass(frozen=True)
class SurfaceVessel:
    """3-DOF surface vessel of section 4.2 (Tables 1-2). State x = [eta (3), nu (3)]."""

    mass_kg: float = 1.1274
    iz_kgm2: float = 1.0
    beta_u: float = 0.0414
    beta_v: float = 0.0414
    beta_r: float = 0.0568
    inversion: Inversion = Inversion.EULER  # how measured_wrench inverts a step
    k: int = 3
    state_labels: tuple[str, ...] = ("north", "east", "psi", "u", "v", "r")

    @property
    def mass_matrix(self) -> FloatArray:
        """M (3, 3) = diag(m, m, I_z) (kg, kg, kg*m^2)."""
        return np.diag([self.mass_kg, self.mass_kg, self.iz_kgm2])

    def drag_and_coriolis(self, nu: FloatArray) -> FloatArray:
        """(C(nu) + D(nu)) nu, with C as printed (its yaw row is zero) and |.| drag."""
        u, v, r = nu
        m = self.mass_kg
        return np.array(
            [
                -m * r * v + self.beta_u * abs(u) * u,
                m * r * u + self.beta_v * abs(v) * v,
                self.beta_r * abs(r) * r,
            ]
        )

    def nu_dot(self, nu: FloatArray, tau: FloatArray) -> FloatArray:
        """M^-1 (tau - (C + D) nu): body accelerations (m/s^2, m/s^2, rad/s^2)."""
        inertia = np.array([self.mass_kg, self.mass_kg, self.iz_kgm2])
        out: FloatArray = (tau - self.drag_and_coriolis(nu)) / inertia
        return out

    @staticmethod
    def eta_dot(eta: FloatArray, nu: FloatArray) -> FloatArray:
        """R(psi) nu (3,): NED velocities [north (m/s), east (m/s), psi rate (rad/s)]."""
        c, s = math.cos(eta[2]), math.sin(eta[2])
        return np.array([c * nu[0] - s * nu[1], s * nu[0] + c * nu[1], nu[2]])

    def step(self, x: FloatArray, tau: FloatArray, dt_s: float) -> FloatArray:
        """The paper's discrete model (forward Euler at T_s); the allocator's model."""
        eta, nu = x[:3], x[3:]
        return np.concatenate(
            [eta + dt_s * self.eta_dot(eta, nu), nu + dt_s * self.nu_dot(nu, tau)]
        )

    def step_rk4(
        self, x: FloatArray, tau: FloatArray, dt_s: float, substeps: int = 8
    ) -> FloatArray:
        """A finer truth: RK4 with tau held constant over dt_s (zero-order hold)."""
        h = dt_s / substeps

        def f(state: FloatArray) -> FloatArray:
            eta, nu = state[:3], state[3:]
            return np.concatenate([self.eta_dot(eta, nu), self.nu_dot(nu, tau)])

        for _ in range(substeps):
            k1 = f(x)
            k2 = f(x + 0.5 * h * k1)
            k3 = f(x + 0.5 * h * k2)
            k4 = f(x + h * k3)
            x = x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
        return x

    def __post_init__(self) -> None:
        require_member("inversion", self.inversion, Inversion)

    def measured_wrench(self, x_prev: FloatArray, x_now: FloatArray, dt_s: float) -> FloatArray:
        """The constant tau that takes nu(t) to nu(t+1) in dt_s.

        "euler" inverts the paper's discrete model exactly (drag and Coriolis at nu(t)).
        "trapezoid" averages them over the step: second-order accurate for the
        continuous-time vessel (docs/algorithm.md, model mismatch), but itself a mismatch
        when the truth *is* the Euler model.
        """
        nu0, nu1 = x_prev[3:], x_now[3:]
        inertial = np.array([self.mass_kg, self.mass_kg, self.iz_kgm2]) * (nu1 - nu0) / dt_s
        if self.inversion is Inversion.EULER:
            return inertial + self.drag_and_coriolis(nu0)
        return inertial + 0.5 * (self.drag_and_coriolis(nu0) + self.drag_and_coriolis(nu1))


def wrap_angle(a: FloatArray | float) -> FloatArray:
    """Wrap to (-pi, pi]."""
    w = np.mod(np.asarray(a, dtype=np.float64) + math.pi, 2 * math.pi) - math.pi
    return np.where(w == -math.pi, math.pi, w)
