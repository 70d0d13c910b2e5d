"""The allocator's plant model as the Kalman filter sees it: one step on the dynamic state.

A :class:`StepModel` maps the tracked state s (ns,) of the plant (x (1,) for the linear plant
of section 4.1, nu = [u, v, r] (3,) body velocities for the vessel, or the pose and the
velocities [north, east, psi, u, v, r] (6,) when the filter is given the pose's noise too)
over one step of ``dt`` seconds under a constant actuator wrench w (k,) (N, N, N*m for the
vessel), and gives the Jacobians the extended Kalman filter of
:mod:`ftcap_hil.core.estimation.kalman` needs. Pure: no I/O.

Why the pose: a real vessel measures its position (GNSS, motion capture) far better, over
the seconds a fault takes to show, than its velocity. A 100 kN loss on a 6000 t vessel is
0.015 m/s after 1 s, under a GNSS/INS velocity noise of 0.01 m/s, but 0.7 m of position
after 10 s, under an RTK noise of 0.01 m: the filter that tracks the pose integrates that
evidence; one that sees the velocities alone cannot.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.plants import Inversion, LinearPlant, SurfaceVessel
from ftcap_hil.core.models.vessel3dof import PlantModel, Vessel3DOF

Prediction = tuple[FloatArray, FloatArray, FloatArray]  # (s1, A, G), as StepModel.predict

# Longest midpoint step ("trapezoid" models): a longer estimation interval (one that spans
# wave periods) is integrated in as many substeps, their Jacobians chained.
MAX_STEP_S = 0.25


def chained(
    one: Callable[[FloatArray, FloatArray, float], Prediction],
    s0: FloatArray,
    w: FloatArray,
    dt: float,
    euler: bool,
) -> Prediction:
    """``one(s, w, h)`` -> (s1, A_i, G_i) over ``dt`` in n equal substeps: one for "euler",
    else the fewest of at most :data:`MAX_STEP_S`. The state is carried from one substep to
    the next and the Jacobians chained: A = A_n ... A_1, G_i folded in as G = A_i G + G_i."""
    n = 1 if euler else max(1, math.ceil(dt / MAX_STEP_S - 1e-9))
    if n == 1:
        return one(s0, w, dt)
    s, A, G = s0, np.eye(s0.size), np.zeros((s0.size, w.size))
    for _ in range(n):
        s, a_i, g_i = one(s, w, dt / n)
        A, G = a_i @ A, a_i @ G + g_i
    return s, A, G


class StepModel(Protocol):
    """One step of the allocator's plant model on its dynamic state s (k,).

    ``predict(s0, w, dt)`` -> (s1, A, G): the state after ``dt`` under the constant actuator
    wrench ``w`` (k,), and the Jacobians A = ds1/ds0 (k x k) and G = ds1/dw (k x k).
    """

    @property
    def k(self) -> int: ...

    @property
    def ns(self) -> int:
        """Size of the tracked state s (k, or 2 k with the pose)."""
        ...

    def innovation(self, y: FloatArray, s: FloatArray) -> FloatArray:
        """y - s (a heading difference wrapped to (-pi, pi])."""
        ...

    def dynamic_state(self, x: FloatArray) -> FloatArray:
        """s (k,), the part of the plant's full state x the filter tracks."""
        ...

    def predict(
        self, s0: FloatArray, w: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(s1, A, G) after ``dt`` seconds under the constant wrench ``w`` (class docstring)."""
        ...


@dataclass(frozen=True)
class LinearStep:
    """x(t+1) = a x(t) + b_v w: the discrete plant of section 4.1 (exact)."""

    plant: LinearPlant
    k: int = 1
    ns: int = 1

    def dynamic_state(self, x: FloatArray) -> FloatArray:
        """x (1,) itself."""
        return np.asarray(x[:1], dtype=np.float64)

    def innovation(self, y: FloatArray, s: FloatArray) -> FloatArray:
        """y - s."""
        out: FloatArray = y - s
        return out

    def predict(
        self, s0: FloatArray, w: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(a s0 + b_v w, [[a]], [[b_v]]): one step of the discrete plant (``dt`` unused)."""
        p = self.plant
        return (
            np.array([p.a * s0[0] + p.b_v * w[0]]),
            np.array([[p.a]]),
            np.array([[p.b_v]]),
        )


class VesselStep:
    """nu(t+1) of a 3-DOF vessel with nu_dot = M^-1 (w - n(nu)), n = (C + D) nu.

    "euler": nu1 = nu0 + dt nu_dot(nu0) (the paper's discrete model, exact for its truth);
    "trapezoid": the explicit midpoint step nu1 = nu0 + dt nu_dot(nu0 + dt/2 nu_dot(nu0)).
    The Jacobian of n is analytic for the paper's vessel and taken by forward differences
    otherwise (any plant with ``nu_dot`` and ``mass_matrix`` works, the general Fossen
    model included).
    """

    k = 3
    ns = 3

    def __init__(self, plant: SurfaceVessel | Vessel3DOF) -> None:
        self.plant = plant
        self._minv = np.asarray(np.linalg.inv(plant.mass_matrix), dtype=np.float64)
        self._inertia = np.diag(plant.mass_matrix).copy()
        self._euler = plant.inversion is Inversion.EULER

    def dynamic_state(self, x: FloatArray) -> FloatArray:
        """nu = [u, v, r] (3,) from x = [north, east, psi, u, v, r]."""
        return np.asarray(x[3:6], dtype=np.float64)

    def innovation(self, y: FloatArray, s: FloatArray) -> FloatArray:
        """y - s."""
        out: FloatArray = y - s
        return out

    def _jacobian(self, nu: FloatArray, w: FloatArray, f0: FloatArray) -> FloatArray:
        """d nu_dot / d nu at nu (3 x 3)."""
        p = self.plant
        if isinstance(p, SurfaceVessel):  # the paper's vessel: analytic
            u, v, r = nu
            m = p.mass_kg
            dn = np.array(
                [
                    [2.0 * p.beta_u * abs(u), -m * r, -m * v],
                    [m * r, 2.0 * p.beta_v * abs(v), m * u],
                    [0.0, 0.0, 2.0 * p.beta_r * abs(r)],
                ]
            )
            out: FloatArray = -dn / self._inertia[:, None]
            return out
        jac = np.empty((3, 3))
        for j in range(3):
            h = 1e-7 * (1.0 + abs(nu[j]))
            nu_h = nu.copy()
            nu_h[j] += h
            jac[:, j] = (self.plant.nu_dot(nu_h, w) - f0) / h
        return jac

    def predict(
        self, s0: FloatArray, w: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """nu1 (3,) after ``dt`` s under the body wrench ``w`` (3,), with A (3, 3) and G (3, 3)
        (substeps: :func:`chained`)."""
        return chained(self._one, s0, w, dt, self._euler)

    def one(
        self, s0: FloatArray, w: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """One step of ``dt`` (no substeps): (nu1, A, G)."""
        return self._one(s0, w, dt)

    def _one(
        self, s0: FloatArray, w: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        if self._euler and isinstance(self.plant, SurfaceVessel):
            return self._one_paper(s0, w, dt)
        f0 = self.plant.nu_dot(s0, w)
        j0 = self._jacobian(s0, w, f0)
        if self._euler:
            A = dt * j0
            A[np.diag_indices(3)] += 1.0
            return s0 + dt * f0, A, dt * self._minv
        half = s0 + 0.5 * dt * f0
        f1 = self.plant.nu_dot(half, w)
        j1 = self._jacobian(half, w, f1)
        d_half = 0.5 * dt * j0  # d half / d s0, minus I
        d_half[np.diag_indices(3)] += 1.0
        A = dt * j1 @ d_half
        A[np.diag_indices(3)] += 1.0
        G = dt * (self._minv + j1 @ (0.5 * dt * self._minv))
        return s0 + dt * f1, A, G

    def _one_paper(
        self, s0: FloatArray, w: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The "euler" step of the paper's vessel in Python floats: SurfaceVessel.nu_dot and
        the analytic Jacobian's operations in their order (the same result to the last bit),
        without numpy's per-call overhead on 3-vectors."""
        p = self.plant
        assert isinstance(p, SurfaceVessel)
        u, v, r = s0.tolist()
        w0, w1, w2 = w.tolist()
        m, iz = p.mass_kg, p.iz_kgm2
        au, av, ar = abs(u), abs(v), abs(r)
        f = (
            (w0 - (-m * r * v + p.beta_u * au * u)) / m,
            (w1 - (m * r * u + p.beta_v * av * v)) / m,
            (w2 - p.beta_r * ar * r) / iz,
        )
        # A = I + dt J, J = -dn / diag(M) (VesselStep._jacobian)
        bu, bv, br = 2.0 * p.beta_u * au, 2.0 * p.beta_v * av, 2.0 * p.beta_r * ar
        A = np.array(
            [
                [dt * (-bu / m) + 1.0, dt * (-(-m * r) / m), dt * (-(-m * v) / m)],
                [dt * (-(m * r) / m), dt * (-bv / m) + 1.0, dt * (-(m * u) / m)],
                [dt * (-0.0 / iz), dt * (-0.0 / iz), dt * (-br / iz) + 1.0],
            ]
        )
        s1 = np.array([u + dt * f[0], v + dt * f[1], r + dt * f[2]])
        return s1, A, dt * self._minv


def _rotation(psi: float) -> tuple[FloatArray, FloatArray]:
    """R(psi) (body to NED, 3 x 3) and dR/dpsi."""
    c, s = math.cos(psi), math.sin(psi)
    r = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    dr = np.array([[-s, -c, 0.0], [c, -s, 0.0], [0.0, 0.0, 0.0]])
    return r, dr


class PoseStep:
    """s = [eta, nu] (6,): the velocity step of :class:`VesselStep` and the kinematics
    eta_dot = R(psi) nu over it, by the same rule ("euler": eta1 = eta0 + dt R(psi0) nu0;
    "trapezoid": the mean of R nu at both ends, psi1 from the mean yaw rate), substeps
    chained as there. Jacobians analytic (module docstring of the filter: EKF)."""

    k = 3
    ns = 6

    def __init__(self, plant: SurfaceVessel | Vessel3DOF) -> None:
        self._vel = VesselStep(plant)
        self._euler = plant.inversion is Inversion.EULER

    def dynamic_state(self, x: FloatArray) -> FloatArray:
        """[north, east, psi, u, v, r] (6,): the full state."""
        return np.asarray(x[:6], dtype=np.float64)

    def innovation(self, y: FloatArray, s: FloatArray) -> FloatArray:
        """y - s with the heading difference wrapped to (-pi, pi]."""
        e: FloatArray = y - s
        e[2] = math.remainder(e[2], 2.0 * math.pi)
        return e

    def predict(
        self, s0: FloatArray, w: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """s1 (6,) after ``dt`` s under the body wrench ``w`` (3,), A (6, 6), G (6, 3)
        (substeps: :func:`chained`)."""
        return chained(self._one, s0, w, dt, self._euler)

    def _one(
        self, s0: FloatArray, w: FloatArray, h: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        eta0, nu0 = s0[:3], s0[3:6]
        nu1, av, gv = self._vel.one(nu0, w, h)
        r0, dr0 = _rotation(float(eta0[2]))
        A = np.zeros((6, 6))
        G = np.zeros((6, 3))
        A[3:, 3:], G[3:] = av, gv
        A[:3, :3] = np.eye(3)
        if self._euler:
            eta1 = eta0 + h * (r0 @ nu0)
            A[:3, 2] += h * (dr0 @ nu0)
            A[:3, 3:] = h * r0
            return np.concatenate([eta1, nu1]), A, G
        psi1 = float(eta0[2] + 0.5 * h * (nu0[2] + nu1[2]))
        r1, dr1 = _rotation(psi1)
        eta1 = eta0 + 0.5 * h * (r0 @ nu0 + r1 @ nu1)
        t1 = dr1 @ nu1  # d (R(psi1) nu1) / d psi1
        dpsi_dnu = 0.5 * h * (np.array([0.0, 0.0, 1.0]) + av[2])
        A[:3, 2] += 0.5 * h * (dr0 @ nu0 + t1)
        A[:3, 3:] = 0.5 * h * (r0 + r1 @ av + np.outer(t1, dpsi_dnu))
        G[:3] = 0.5 * h * (r1 @ gv + np.outer(t1, 0.5 * h * gv[2]))
        eta1[2] = psi1
        return np.concatenate([eta1, nu1]), A, G


def inv_small(a: FloatArray) -> FloatArray:
    """Inverse of a symmetric positive definite 1 x 1, 2 x 2 or 3 x 3 matrix by cofactors
    (numpy's general inverse costs ~20 us of call overhead at this size), in Python floats
    (an element read from an array costs more than the multiplication)."""
    n = a.shape[0]
    if n == 1:
        return np.array([[1.0 / float(a[0, 0])]])
    if n == 2:
        (a00, a01), (a10, a11) = a.tolist()
        det = a00 * a11 - a01 * a10
        two: FloatArray = np.array([[a11, -a01], [-a10, a00]]) / det
        return two
    if n == 3:
        (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a.tolist()
        c00 = a11 * a22 - a12 * a21
        c10 = a12 * a20 - a10 * a22
        c20 = a10 * a21 - a11 * a20
        det = a00 * c00 + a01 * c10 + a02 * c20
        c = np.array(
            [
                [c00, a02 * a21 - a01 * a22, a01 * a12 - a02 * a11],
                [c10, a00 * a22 - a02 * a20, a02 * a10 - a00 * a12],
                [c20, a01 * a20 - a00 * a21, a00 * a11 - a01 * a10],
            ]
        )
        out: FloatArray = c / det
        return out
    return np.asarray(np.linalg.inv(a), dtype=np.float64)


def step_model(plant: PlantModel, with_pose: bool = False) -> StepModel:
    """The filter's view of a plant model; ``with_pose``: a vessel's pose is measured and
    tracked too (:class:`PoseStep`)."""
    if isinstance(plant, LinearPlant):
        return LinearStep(plant)
    return PoseStep(plant) if with_pose else VesselStep(plant)
