"""A general 3-DOF surface vessel in Fossen's notation: the truth model of the presets.

Beside the paper's models in ``plants`` (which stay exactly as they are, so the paper
scenarios keep their numbers), this is the model a realistic vessel is simulated with:
rigid-body and added mass with a CG offset, Coriolis of both, linear and quadratic damping
per axis with cross terms, an ocean current through the relative velocity and an
environmental wrench. The allocator side uses the same class with nu_c = 0 (it knows no
current) through ``measured_wrench``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from ftcap_hil.core.errors import require_member
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.plants import Inversion, LinearPlant, SurfaceVessel

DAMPING_KEYS = (
    "X_u", "Y_v", "Y_r", "N_v", "N_r", "X_uu", "X_uuu",
    "Y_vv", "Y_rv", "Y_vr", "Y_rr", "N_vv", "N_rv", "N_vr", "N_rr",
)  # fmt: skip


@dataclass(frozen=True)
class Vessel3DOF:
    """A 3-DOF surface vessel in Fossen's notation (Handbook of Marine Craft Hydrodynamics
    and Motion Control, 2021, ch. 6-7). State x = [north, east, psi, u, v, r] (m, rad, m/s,
    rad/s); body frame x forward, y starboard, origin CO; tau = [X, Y, N] (N, N, N m).

    Kinetics, with the ocean current irrotational and constant in NED over an instant::

        M_RB nu_dot + C_RB(nu) nu + M_A nu_r_dot + C_A(nu_r) nu_r + D(nu_r) nu_r = tau + tau_env
        nu_r = nu - nu_c,   nu_c = R(psi)^T [V_cN, V_cE, 0],   nu_c_dot = [r v_c, -r u_c, 0]

    so that M nu_dot = tau + tau_env - C_RB(nu) nu - C_A(nu_r) nu_r - D(nu_r) nu_r
    + M_A nu_c_dot, with M = M_RB + M_A and::

        M_RB = [[m, 0, 0], [0, m, m x_g], [0, m x_g, I_z]]         (y_g = 0; I_z about CO)
        M_A  = -[[X_udot, 0, 0], [0, Y_vdot, Y_rdot], [0, N_vdot, N_rdot]]
        C_RB(nu) nu   = [-m (v + x_g r) r,  m u r,  m x_g u r]
        C_A(nu_r) nu_r = [ (Y_vdot v_r + Yr_bar r) r,  -X_udot u_r r,
                           (X_udot - Y_vdot) u_r v_r - Yr_bar u_r r ],  Yr_bar = (Y_rdot + N_vdot)/2

    (C_RB and C_A skew-symmetric: they do no work). Damping, linear plus the per-axis and
    cross quadratic terms of Skjetne, Smogeli & Fossen (2004), ``D(nu_r) nu_r`` =::

        [-(X_u + X_uu |u| + X_uuu u^2) u,
         -(Y_v + Y_vv |v| + Y_rv |r|) v - (Y_r + Y_vr |v| + Y_rr |r|) r,
         -(N_v + N_vv |v| + N_rv |r|) v - (N_r + N_vr |v| + N_rr |r|) r]    (u, v, r relative)

    Names follow the derivatives: ``X_uu`` is X_|u|u, ``Y_rv`` is Y_|r|v, ``N_vr`` is N_|v|r.
    ``coriolis=False`` drops C_RB and C_A (a linear DP model such as Fossen's supply vessel).
    The paper's SurfaceVessel is the case x_g = 0, no added mass, X_uu = -beta_u,
    Y_vv = -beta_v, N_rr = -beta_r, all else 0 (``from_surface_vessel``).
    ``nu_dot`` and ``measured_wrench`` accept batches (..., 3) / (..., 6); ``step`` and
    ``step_rk4`` advance one state (6,).
    """

    mass_kg: float
    iz_kgm2: float
    xg_m: float = 0.0
    X_udot: float = 0.0
    Y_vdot: float = 0.0
    Y_rdot: float = 0.0
    N_vdot: float = 0.0
    N_rdot: float = 0.0
    X_u: float = 0.0
    Y_v: float = 0.0
    Y_r: float = 0.0
    N_v: float = 0.0
    N_r: float = 0.0
    X_uu: float = 0.0
    X_uuu: float = 0.0
    Y_vv: float = 0.0
    Y_rv: float = 0.0
    Y_vr: float = 0.0
    Y_rr: float = 0.0
    N_vv: float = 0.0
    N_rv: float = 0.0
    N_vr: float = 0.0
    N_rr: float = 0.0
    coriolis: bool = True
    inversion: Inversion = Inversion.EULER  # how measured_wrench inverts a step
    k: int = field(default=3, init=False)
    state_labels: tuple[str, ...] = field(
        default=("north", "east", "psi", "u", "v", "r"), init=False
    )

    def __post_init__(self) -> None:
        require_member("inversion", self.inversion, Inversion)
        if not self.mass_kg > 0.0 or not self.iz_kgm2 > 0.0:
            raise ValueError(f"mass_kg and iz_kgm2 must be > 0, got {self.mass_kg}, {self.iz_kgm2}")
        if np.any(np.linalg.eigvalsh(0.5 * (self.mass_matrix + self.mass_matrix.T)) <= 0.0):
            raise ValueError("M = M_RB + M_A is not positive definite")

    @classmethod
    def from_surface_vessel(cls, sv: SurfaceVessel) -> Vessel3DOF:
        """The paper's vessel (section 4.2) in this model's parameters."""
        return cls(
            mass_kg=sv.mass_kg,
            iz_kgm2=sv.iz_kgm2,
            X_uu=-sv.beta_u,
            Y_vv=-sv.beta_v,
            N_rr=-sv.beta_r,
            inversion=sv.inversion,
        )

    @property
    def rigid_body_mass(self) -> FloatArray:
        """M_RB (3, 3): kg, kg m, kg m^2."""
        m, mx = self.mass_kg, self.mass_kg * self.xg_m
        return np.array([[m, 0.0, 0.0], [0.0, m, mx], [0.0, mx, self.iz_kgm2]])

    @property
    def added_mass(self) -> FloatArray:
        """M_A (3, 3) = -[[X_udot, 0, 0], [0, Y_vdot, Y_rdot], [0, N_vdot, N_rdot]]."""
        return -np.array(
            [
                [self.X_udot, 0.0, 0.0],
                [0.0, self.Y_vdot, self.Y_rdot],
                [0.0, self.N_vdot, self.N_rdot],
            ]
        )

    @cached_property
    def mass_matrix(self) -> FloatArray:
        """M = M_RB + M_A (3, 3)."""
        out: FloatArray = self.rigid_body_mass + self.added_mass
        return out

    @cached_property
    def _m_inv_t(self) -> FloatArray:
        out = np.linalg.inv(self.mass_matrix).T  # row-vector form: a @ M^-T
        return np.asarray(out, dtype=np.float64)

    def coriolis_rigid_body(self, nu: FloatArray) -> FloatArray:
        """C_RB(nu) nu, shape of nu (N, N, N m)."""
        u, v, r = nu[..., 0], nu[..., 1], nu[..., 2]
        m, mx = self.mass_kg, self.mass_kg * self.xg_m
        return np.stack([-m * v * r - mx * r * r, m * u * r, mx * u * r], axis=-1)

    def coriolis_added(self, nu_r: FloatArray) -> FloatArray:
        """C_A(nu_r) nu_r, shape of nu_r (N, N, N m); r_r = r (irrotational current)."""
        u, v, r = nu_r[..., 0], nu_r[..., 1], nu_r[..., 2]
        yr = 0.5 * (self.Y_rdot + self.N_vdot)
        return np.stack(
            [
                (self.Y_vdot * v + yr * r) * r,
                -self.X_udot * u * r,
                (self.X_udot - self.Y_vdot) * u * v - yr * u * r,
            ],
            axis=-1,
        )

    def damping(self, nu_r: FloatArray) -> FloatArray:
        """D(nu_r) nu_r (class docstring), shape of nu_r (N, N, N m)."""
        if np.shape(nu_r) == (3,):  # one state: the same operations on Python floats
            d0, d1, d2 = self._damping_one(*(float(x) for x in nu_r))
            return np.array([-d0, -d1, -d2])
        u, v, r = nu_r[..., 0], nu_r[..., 1], nu_r[..., 2]
        au, av, ar = np.abs(u), np.abs(v), np.abs(r)
        return -np.stack(
            [
                (self.X_u + self.X_uu * au + self.X_uuu * u * u) * u,
                (self.Y_v + self.Y_vv * av + self.Y_rv * ar) * v
                + (self.Y_r + self.Y_vr * av + self.Y_rr * ar) * r,
                (self.N_v + self.N_vv * av + self.N_rv * ar) * v
                + (self.N_r + self.N_vr * av + self.N_rr * ar) * r,
            ],
            axis=-1,
        )

    def hydro_and_coriolis(self, nu: FloatArray, nu_c: FloatArray | None = None) -> FloatArray:
        """n(nu) = C_RB(nu) nu + C_A(nu_r) nu_r + D(nu_r) nu_r - M_A nu_c_dot, so that
        M nu_dot = tau + tau_env - n. With nu_c = None (no current), nu_r = nu."""
        nu = np.asarray(nu, dtype=np.float64)
        feed: FloatArray | float = 0.0
        if nu_c is None:
            nu_r = nu
        else:
            nu_c = np.broadcast_to(np.asarray(nu_c, dtype=np.float64), nu.shape)
            nu_r = nu - nu_c
            r = nu[..., 2]
            nu_c_dot = np.stack([r * nu_c[..., 1], -r * nu_c[..., 0], 0.0 * r], axis=-1)
            feed = nu_c_dot @ self.added_mass.T
        out = self.damping(nu_r) - feed
        if self.coriolis:
            out = out + self.coriolis_rigid_body(nu) + self.coriolis_added(nu_r)
        result: FloatArray = out
        return result

    def nu_dot(
        self,
        nu: FloatArray,
        tau: FloatArray,
        nu_c_body: FloatArray | None = None,
        tau_env: FloatArray | None = None,
    ) -> FloatArray:
        """Body accelerations (m/s^2, m/s^2, rad/s^2) = M^-1 (tau + tau_env - n(nu)).

        ``nu_c_body``: the current's velocity in the body frame, [u_c, v_c, 0] (m/s);
        ``tau_env``: environmental body wrench (wind, waves) [X, Y, N]."""
        if nu_c_body is None and tau_env is None and np.shape(nu) == (3,) == np.shape(tau):
            return self._nu_dot_one(nu, tau)
        rhs = np.asarray(tau, dtype=np.float64) - self.hydro_and_coriolis(nu, nu_c_body)
        if tau_env is not None:
            rhs = rhs + tau_env
        out: FloatArray = rhs @ self._m_inv_t
        return out

    def _nu_dot_one(self, nu: FloatArray, tau: FloatArray) -> FloatArray:
        """``nu_dot`` of one state without current or environment: the same operations in
        the same order on Python floats (numpy's per-call overhead on (3,) arrays is ten
        times the arithmetic; the filter's Jacobian takes several per sample), then the one
        product with M^-T as there, so the result is the same to the last bit."""
        u, v, r = (float(x) for x in nu)
        d0, d1, d2 = self._damping_one(u, v, r)
        n0, n1, n2 = -d0 - 0.0, -d1 - 0.0, -d2 - 0.0  # damping(nu) - feed, feed = 0.0
        if self.coriolis:
            m, mx = self.mass_kg, self.mass_kg * self.xg_m
            yr = 0.5 * (self.Y_rdot + self.N_vdot)
            n0 = n0 + (-m * v * r - mx * r * r) + (self.Y_vdot * v + yr * r) * r
            n1 = n1 + m * u * r + -self.X_udot * u * r
            n2 = n2 + mx * u * r + ((self.X_udot - self.Y_vdot) * u * v - yr * u * r)
        t0, t1, t2 = (float(x) for x in tau)
        out: FloatArray = np.array([t0 - n0, t1 - n1, t2 - n2]) @ self._m_inv_t
        return out

    def _damping_one(self, u: float, v: float, r: float) -> tuple[float, float, float]:
        """-D(nu) nu of one state in Python floats, the operations of ``damping`` in order."""
        au, av, ar = abs(u), abs(v), abs(r)
        d0 = (self.X_u + self.X_uu * au + self.X_uuu * u * u) * u
        d1 = (self.Y_v + self.Y_vv * av + self.Y_rv * ar) * v
        d1 = d1 + (self.Y_r + self.Y_vr * av + self.Y_rr * ar) * r
        d2 = (self.N_v + self.N_vv * av + self.N_rv * ar) * v
        d2 = d2 + (self.N_r + self.N_vr * av + self.N_rr * ar) * r
        return d0, d1, d2

    eta_dot = staticmethod(SurfaceVessel.eta_dot)

    @staticmethod
    def current_body(psi: float, current_ned: FloatArray | None) -> FloatArray | None:
        """nu_c = R(psi)^T [V_cN, V_cE, 0] (m/s), None for no current."""
        if current_ned is None:
            return None
        c, s = math.cos(psi), math.sin(psi)
        vn, ve = float(current_ned[0]), float(current_ned[1])
        return np.array([c * vn + s * ve, -s * vn + c * ve, 0.0])

    @cached_property
    def _m_inv_rows(self) -> tuple[tuple[float, float, float], ...]:
        m = np.linalg.inv(self.mass_matrix)
        return tuple((float(row[0]), float(row[1]), float(row[2])) for row in m)

    def _derivative(
        self,
        s: list[float],
        tau: tuple[float, float, float],
        cur: tuple[float, float] | None,
        env: tuple[float, float, float],
    ) -> list[float]:
        """x_dot of one state in Python floats: the equations of ``nu_dot`` (numpy's call
        overhead on (3,) arrays is several times the arithmetic of one RK4 stage)."""
        psi, u, v, r = s[2], s[3], s[4], s[5]
        c, sn = math.cos(psi), math.sin(psi)
        uc = vc = 0.0
        if cur is not None:
            uc, vc = c * cur[0] + sn * cur[1], -sn * cur[0] + c * cur[1]
        ur, vr = u - uc, v - vc
        au, av, ar = abs(ur), abs(vr), abs(r)
        fx = tau[0] + env[0] + (self.X_u + self.X_uu * au + self.X_uuu * ur * ur) * ur
        fy = tau[1] + env[1] + (self.Y_v + self.Y_vv * av + self.Y_rv * ar) * vr
        fy += (self.Y_r + self.Y_vr * av + self.Y_rr * ar) * r
        fn = tau[2] + env[2] + (self.N_v + self.N_vv * av + self.N_rv * ar) * vr
        fn += (self.N_r + self.N_vr * av + self.N_rr * ar) * r
        fx, fy, fn = fx - self.X_udot * r * vc, fy + self.Y_vdot * r * uc, fn + self.N_vdot * r * uc
        if self.coriolis:
            m, mx, yr = self.mass_kg, self.mass_kg * self.xg_m, 0.5 * (self.Y_rdot + self.N_vdot)
            fx -= -m * v * r - mx * r * r + (self.Y_vdot * vr + yr * r) * r
            fy -= m * u * r - self.X_udot * ur * r
            fn -= mx * u * r + (self.X_udot - self.Y_vdot) * ur * vr - yr * ur * r
        (a, b, e), (f, g, h), (i, j, k) = self._m_inv_rows
        return [
            c * u - sn * v, sn * u + c * v, r,
            a * fx + b * fy + e * fn, f * fx + g * fy + h * fn, i * fx + j * fy + k * fn,
        ]  # fmt: skip

    @staticmethod
    def _held(
        tau: FloatArray, current_ned: FloatArray | None, tau_env: FloatArray | None
    ) -> tuple[tuple[float, float, float], tuple[float, float] | None, tuple[float, float, float]]:
        t = (float(tau[0]), float(tau[1]), float(tau[2]))
        cur = None if current_ned is None else (float(current_ned[0]), float(current_ned[1]))
        e = (0.0, 0.0, 0.0) if tau_env is None else tau_env
        return t, cur, (float(e[0]), float(e[1]), float(e[2]))

    def step(
        self,
        x: FloatArray,
        tau: FloatArray,
        dt_s: float,
        current_ned: FloatArray | None = None,
        tau_env: FloatArray | None = None,
    ) -> FloatArray:
        """Forward Euler over dt_s for one state x (6,); ``current_ned`` = [V_cN, V_cE]
        (m/s) and ``tau_env`` (body wrench) held over the step."""
        s = [float(e) for e in x]
        d = self._derivative(s, *self._held(tau, current_ned, tau_env))
        return np.array([a + dt_s * b for a, b in zip(s, d, strict=True)])

    def step_rk4(
        self,
        x: FloatArray,
        tau: FloatArray,
        dt_s: float,
        substeps: int = 8,
        current_ned: FloatArray | None = None,
        tau_env: FloatArray | None = None,
    ) -> FloatArray:
        """RK4 for one state x (6,) with tau, the NED current and tau_env held over dt_s
        (zero-order hold); the current is rotated into the body frame at every stage."""
        held = self._held(tau, current_ned, tau_env)
        h = dt_s / substeps
        s = [float(e) for e in x]
        for _ in range(substeps):
            k1 = self._derivative(s, *held)
            k2 = self._derivative([a + 0.5 * h * b for a, b in zip(s, k1, strict=True)], *held)
            k3 = self._derivative([a + 0.5 * h * b for a, b in zip(s, k2, strict=True)], *held)
            k4 = self._derivative([a + h * b for a, b in zip(s, k3, strict=True)], *held)
            s = [
                a + (h / 6.0) * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
                for a, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4, strict=True)
            ]
        return np.array(s)

    def measured_wrench(self, x_prev: FloatArray, x_now: FloatArray, dt_s: float) -> FloatArray:
        """The constant tau that takes nu(t) to nu(t+1) in dt_s, by the allocator's model:
        it knows no current or environment (nu_c = 0, tau_env = 0). ``Inversion.EULER``
        inverts ``step`` exactly; ``TRAPEZOID`` averages n(nu) over the step
        (SurfaceVessel.measured_wrench)."""
        nu0, nu1 = x_prev[..., 3:], x_now[..., 3:]
        inertial = (nu1 - nu0) @ self.mass_matrix.T / dt_s
        if self.inversion is Inversion.EULER:
            out: FloatArray = inertial + self.hydro_and_coriolis(nu0)
        else:
            out = inertial + 0.5 * (self.hydro_and_coriolis(nu0) + self.hydro_and_coriolis(nu1))
        return out

    def scaled(self, mass: float = 1.0, damping: float = 1.0) -> Vessel3DOF:
        """A copy with M_RB and M_A multiplied by ``mass`` (x_g unchanged) and every damping
        coefficient by ``damping`` (a model error for the allocator's copy)."""
        if not mass > 0.0 or not damping >= 0.0:
            raise ValueError(f"scaled: need mass > 0 and damping >= 0, got {mass}, {damping}")
        inertia = ("mass_kg", "iz_kgm2", "X_udot", "Y_vdot", "Y_rdot", "N_vdot", "N_rdot")
        values = {k: getattr(self, k) * mass for k in inertia}
        values.update({k: getattr(self, k) * damping for k in DAMPING_KEYS})
        return replace(self, **values)


# A plant model the allocator can be told: the paper's linear plant or vessel, or this one.
PlantModel = LinearPlant | SurfaceVessel | Vessel3DOF
