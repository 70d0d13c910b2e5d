"""A 6-DOF underwater vehicle in Fossen's notation: the rigid body an ROV is simulated as.

Fossen (Handbook of Marine Craft Hydrodynamics and Motion Control, 2021, ch. 2-4 and 6),
for a vehicle whose body origin is its centre of gravity and whose added mass and damping
are diagonal (the form the identified BlueROV2 models take)::

    eta = [n, e, d, phi, theta, psi]        NED position (m), Euler angles zyx (rad)
    nu  = [u, v, w, p, q, r]                body velocities (m/s, rad/s)
    eta_dot = J(eta) nu
    M_RB nu_dot + C_RB(nu) nu + M_A nu_r_dot + C_A(nu_r) nu_r + D(nu_r) nu_r + g(eta) = tau

with nu_r = nu - nu_c the velocity relative to a current constant and irrotational in NED
(nu_c = [R^T v_c; 0], nu_c_dot = [-omega x (R^T v_c); 0]), M_RB = diag(m, m, m, I_x, I_y,
I_z), M_A = diag(a) and, in the vector form of the skew-symmetric matrices,

    C_RB(nu) nu = [m omega x v;  omega x I omega]
    C_A(nu_r) nu_r = [omega_r x A_v v_r;  v_r x A_v v_r + omega_r x A_w omega_r]
    D(nu_r) nu_r = (d_lin + d_quad |nu_r|) nu_r                  (per axis)
    g(eta) = [(W - B) s_theta, -(W - B) c_theta s_phi, -(W - B) c_theta c_phi,
              -(y_g W - y_b B) c_theta c_phi + (z_g W - z_b B) c_theta s_phi,
              (z_g W - z_b B) s_theta + (x_g W - x_b B) c_theta c_phi,
              -(x_g W - x_b B) c_theta s_phi - (y_g W - y_b B) s_theta]

(W = m g, B = rho g V; C_RB and C_A do no work, nu^T C nu = 0). A centre of gravity off
the origin would add M_RB's coupling terms: the identified models put the origin at the
CG, and the constructor refuses another (``cg_m`` must be zero). The Euler angles are
singular at theta = +-90 deg, a pitch an ROV never flies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ftcap_hil.core.messages import FloatArray


def rotation(phi: float, theta: float, psi: float) -> FloatArray:
    """R (3, 3): body -> NED, zyx convention (R = Rz(psi) Ry(theta) Rx(phi))."""
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    return np.array(
        [
            [cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st],
            [sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf],
            [-st, ct * sf, ct * cf],
        ]
    )


def euler_rates(phi: float, theta: float) -> FloatArray:
    """T (3, 3): body rates [p, q, r] -> Euler angle rates (singular at theta = +-pi/2)."""
    cf, sf = math.cos(phi), math.sin(phi)
    ct, tt = math.cos(theta), math.tan(theta)
    return np.array([[1.0, sf * tt, cf * tt], [0.0, cf, -sf], [0.0, sf / ct, cf / ct]])


@dataclass(frozen=True)
class Vehicle6DOF:
    """A rigid underwater vehicle (module docstring); SI units, magnitudes positive.

    ``inertia_kgm2`` (I_x, I_y, I_z) about the CG; ``cb_m`` the centre of buoyancy from the
    CG (body axes, z down); ``added_mass`` (6,) the diagonal of M_A; ``damping_linear`` and
    ``damping_quadratic`` (6,) per-axis coefficients (N s/m, N s^2/m^2 and the rotational
    counterparts). State x = [eta, nu] (12,).
    """

    mass_kg: float
    volume_m3: float
    inertia_kgm2: tuple[float, float, float]
    cb_m: tuple[float, float, float]
    added_mass: tuple[float, ...]
    damping_linear: tuple[float, ...]
    damping_quadratic: tuple[float, ...]
    water_density_kgm3: float = 1000.0
    gravity_ms2: float = 9.81
    cg_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("added_mass", "damping_linear", "damping_quadratic"):
            values = getattr(self, name)
            if len(values) != 6 or not all(math.isfinite(v) and v >= 0.0 for v in values):
                raise ValueError(f"{name}: need 6 finite numbers >= 0, got {values}")
        if len(self.inertia_kgm2) != 3 or not all(i > 0.0 for i in self.inertia_kgm2):
            raise ValueError(f"inertia_kgm2: need 3 numbers > 0, got {self.inertia_kgm2}")
        positive = (self.mass_kg, self.volume_m3, self.water_density_kgm3, self.gravity_ms2)
        if not all(math.isfinite(v) and v > 0.0 for v in positive):
            raise ValueError("mass, volume, water density and gravity must be > 0")
        if any(self.cg_m):
            raise ValueError(f"cg_m: the body origin is the CG here, got {self.cg_m}")

    @property
    def weight_n(self) -> float:
        """W = m g (N)."""
        return self.mass_kg * self.gravity_ms2

    @property
    def buoyancy_n(self) -> float:
        """B = rho g V (N)."""
        return self.water_density_kgm3 * self.gravity_ms2 * self.volume_m3

    @cached_property
    def mass_matrix(self) -> FloatArray:
        """M = M_RB + M_A (6, 6), diagonal."""
        m = self.mass_kg
        rb = np.array([m, m, m, *self.inertia_kgm2])
        return np.diag(rb + np.array(self.added_mass))

    @cached_property
    def _mass_diagonal(self) -> FloatArray:
        diagonal: FloatArray = np.diag(self.mass_matrix).copy()
        return diagonal

    def restoring(self, eta: FloatArray) -> FloatArray:
        """g(eta) (6,): weight and buoyancy as they enter on the left of the kinetics."""
        phi, theta = float(eta[3]), float(eta[4])
        cf, sf, ct, st = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta)
        W, B = self.weight_n, self.buoyancy_n
        xg, yg, zg = self.cg_m
        xb, yb, zb = self.cb_m
        x_, y_, z_ = xg * W - xb * B, yg * W - yb * B, zg * W - zb * B
        return np.array(
            [
                (W - B) * st,
                -(W - B) * ct * sf,
                -(W - B) * ct * cf,
                -y_ * ct * cf + z_ * ct * sf,
                z_ * st + x_ * ct * cf,
                -x_ * ct * sf - y_ * st,
            ]
        )

    def coriolis(self, nu: FloatArray, nu_r: FloatArray) -> FloatArray:
        """C_RB(nu) nu + C_A(nu_r) nu_r (6,): the rigid body's and the added mass's."""
        v, w = nu[:3], nu[3:]
        inertia = np.array(self.inertia_kgm2)
        a = np.array(self.added_mass)
        vr, wr = nu_r[:3], nu_r[3:]
        av, aw = a[:3] * vr, a[3:] * wr
        rb = np.concatenate([self.mass_kg * np.cross(w, v), np.cross(w, inertia * w)])
        added = np.concatenate([np.cross(wr, av), np.cross(vr, av) + np.cross(wr, aw)])
        total: FloatArray = rb + added
        return total

    def damping(self, nu_r: FloatArray) -> FloatArray:
        """D(nu_r) nu_r (6,)."""
        lin = np.array(self.damping_linear)
        quad = np.array(self.damping_quadratic)
        drag: FloatArray = (lin + quad * np.abs(nu_r)) * nu_r
        return drag

    def derivative_reference(
        self, x: FloatArray, tau: FloatArray, current_ned: FloatArray | None = None
    ) -> FloatArray:
        """:meth:`derivative` composed of the numpy terms above: the reference it is tested
        against (each term readable on its own; several times slower)."""
        eta, nu = x[:6], x[6:]
        R = rotation(float(eta[3]), float(eta[4]), float(eta[5]))
        eta_dot = np.concatenate([R @ nu[:3], euler_rates(float(eta[3]), float(eta[4])) @ nu[3:]])
        nu_r = nu.copy()
        nu_c_dot = np.zeros(6)
        if current_ned is not None:
            vc = R.T @ np.asarray(current_ned, dtype=np.float64)
            nu_r[:3] -= vc
            nu_c_dot[:3] = -np.cross(nu[3:], vc)
        a = np.array(self.added_mass)
        rhs = (
            np.asarray(tau, dtype=np.float64)
            - self.coriolis(nu, nu_r)
            - self.damping(nu_r)
            - self.restoring(eta)
            + a * nu_c_dot
        )
        return np.concatenate([eta_dot, rhs / self._mass_diagonal])

    @cached_property
    def _constants(self) -> tuple[float, ...]:
        """Everything :meth:`derivative` needs, as Python floats (one tuple unpacked)."""
        W, B = self.weight_n, self.buoyancy_n
        xb, yb, zb = self.cb_m  # cg_m is zero (checked at construction)
        return (
            self.mass_kg, *self.inertia_kgm2, *self.added_mass, *self.damping_linear,
            *self.damping_quadratic, *(float(v) for v in self._mass_diagonal),
            W - B, -xb * B, -yb * B, -zb * B,
        )  # fmt: skip

    def derivative(
        self, x: FloatArray, tau: FloatArray, current_ned: FloatArray | None = None
    ) -> FloatArray:
        """x_dot (12,) for state x = [eta, nu], body wrench ``tau`` (6,) and a current
        (3,) in NED (m/s), None for still water. The module docstring's equations in Python
        floats: numpy's per-call cost on (3,) vectors made the array form
        (:meth:`derivative_reference`, to which it is tested equal) 5-8 times slower."""
        (m, ix, iy, iz, a1, a2, a3, a4, a5, a6, l1, l2, l3, l4, l5, l6, q1, q2, q3, q4, q5,
         q6, m1, m2, m3, m4, m5, m6, wb, xb_, yb_, zb_) = self._constants  # fmt: skip
        _n, _e, _d, phi, th, psi, u, v, w, p, q, r = x.tolist()
        X, Y, Z, K, M, N = tau.tolist()
        cf, sf, ct, st = math.cos(phi), math.sin(phi), math.cos(th), math.sin(th)
        cp, sp = math.cos(psi), math.sin(psi)
        # R (body -> NED), zyx
        r11, r12, r13 = cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st
        r21, r22, r23 = sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf
        r31, r32, r33 = -st, ct * sf, ct * cf
        ur, vr, wr = u, v, w
        dcu = dcv = dcw = 0.0
        if current_ned is not None:
            cn, ce, cd = (float(c) for c in current_ned)
            vcu = r11 * cn + r21 * ce + r31 * cd  # R^T v_c
            vcv = r12 * cn + r22 * ce + r32 * cd
            vcw = r13 * cn + r23 * ce + r33 * cd
            ur, vr, wr = u - vcu, v - vcv, w - vcw
            dcu, dcv, dcw = -(q * vcw - r * vcv), -(r * vcu - p * vcw), -(p * vcv - q * vcu)
        # C_RB nu = [m w x v; w x I w]
        crb = (m * (q * w - r * v), m * (r * u - p * w), m * (p * v - q * u),
               (iz - iy) * q * r, (ix - iz) * r * p, (iy - ix) * p * q)  # fmt: skip
        # C_A nu_r = [w x A_v v_r; v_r x A_v v_r + w x A_w w]   (omega_r = omega)
        au, av, aw, ap, aq, ar = a1 * ur, a2 * vr, a3 * wr, a4 * p, a5 * q, a6 * r
        ca = (q * aw - r * av, r * au - p * aw, p * av - q * au,
              vr * aw - wr * av + q * ar - r * aq,
              wr * au - ur * aw + r * ap - p * ar,
              ur * av - vr * au + p * aq - q * ap)  # fmt: skip
        d = ((l1 + q1 * abs(ur)) * ur, (l2 + q2 * abs(vr)) * vr, (l3 + q3 * abs(wr)) * wr,
             (l4 + q4 * abs(p)) * p, (l5 + q5 * abs(q)) * q, (l6 + q6 * abs(r)) * r)  # fmt: skip
        g = (wb * st, -wb * ct * sf, -wb * ct * cf,
             -yb_ * ct * cf + zb_ * ct * sf,
             zb_ * st + xb_ * ct * cf,
             -xb_ * ct * sf - yb_ * st)  # fmt: skip
        tt = st / ct
        return np.array(
            [
                r11 * u + r12 * v + r13 * w,
                r21 * u + r22 * v + r23 * w,
                r31 * u + r32 * v + r33 * w,
                p + sf * tt * q + cf * tt * r,
                cf * q - sf * r,
                (sf * q + cf * r) / ct,
                (X - crb[0] - ca[0] - d[0] - g[0] + a1 * dcu) / m1,
                (Y - crb[1] - ca[1] - d[1] - g[1] + a2 * dcv) / m2,
                (Z - crb[2] - ca[2] - d[2] - g[2] + a3 * dcw) / m3,
                (K - crb[3] - ca[3] - d[3] - g[3]) / m4,
                (M - crb[4] - ca[4] - d[4] - g[4]) / m5,
                (N - crb[5] - ca[5] - d[5] - g[5]) / m6,
            ]
        )

    def step_rk4(
        self,
        x: FloatArray,
        tau: FloatArray,
        dt_s: float,
        current_ned: FloatArray | None = None,
    ) -> FloatArray:
        """x after ``dt_s`` of a constant wrench and current (classic Runge-Kutta 4)."""
        k1 = self.derivative(x, tau, current_ned)
        k2 = self.derivative(x + 0.5 * dt_s * k1, tau, current_ned)
        k3 = self.derivative(x + 0.5 * dt_s * k2, tau, current_ned)
        k4 = self.derivative(x + dt_s * k3, tau, current_ned)
        return x + (dt_s / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
