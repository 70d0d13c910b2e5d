"""First-order wave loads: a sampled JONSWAP sea and the Froude-Krylov force on a box.

Long-crested waves, N components from a JONSWAP spectrum (DNV-RP-C205 3.5.5; gamma = 1 is
Pierson-Moskowitz) on [w_lo, w_hi] x w_p, deep water (k = w^2 / g). The force on the hull
is the Froude-Krylov force on a box L x B x T (the undisturbed wave pressure integrated
over its walls) scaled by the block coefficient, times a per-axis ``force_factor`` that
stands in for diffraction (``froude_krylov``; docs/vessels.md compares it with ShipX force
RAOs). Used by ``sim.environment``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.messages import FloatArray

G_M_S2 = 9.81


def jonswap(omega_rad_s: FloatArray, hs_m: float, tp_s: float, gamma: float = 3.3) -> FloatArray:
    """JONSWAP wave spectrum S(w) (m^2 s / rad) of DNV-RP-C205 eq. 3.5.5::

    S = (1 - 0.287 ln gamma) 5/16 Hs^2 w_p^4 w^-5 exp(-5/4 (w_p/w)^4)
        * gamma^exp(-(w - w_p)^2 / (2 sigma^2 w_p^2)),  sigma = 0.07 (w <= w_p), 0.09

    with w_p = 2 pi / Tp; its integral is close to Hs^2 / 16 (exactly for gamma = 1, PM).
    """
    w = np.asarray(omega_rad_s, dtype=np.float64)
    wp = 2.0 * math.pi / tp_s
    sigma = np.where(w <= wp, 0.07, 0.09)
    pm = 5.0 / 16.0 * hs_m**2 * wp**4 * w**-5.0 * np.exp(-1.25 * (wp / w) ** 4)
    peak = gamma ** np.exp(-((w - wp) ** 2) / (2.0 * sigma**2 * wp**2))
    out: FloatArray = (1.0 - 0.287 * math.log(gamma)) * pm * peak
    return out


@dataclass(frozen=True)
class HullGeometry:
    """What the wind and wave models need of the vessel (SI): the box L x B x T of the
    Froude-Krylov force (scaled by the block coefficient C_B, so that long waves push the
    hull's true displacement), the projected wind areas and the lateral area centroid's
    longitudinal position s_L (m, forward of CO)."""

    l_oa_m: float
    beam_m: float
    draft_m: float
    block_coefficient: float = 1.0
    a_front_m2: float = 0.0
    a_lateral_m2: float = 0.0
    s_l_m: float = 0.0
    rho_water_kg_m3: float = 1025.0


@dataclass(frozen=True)
class WaveConfig:
    hs_m: float = 0.0
    tp_s: float = 8.0
    gamma: float = 3.3
    direction_rad: float = 0.0
    n_components: int = 100
    omega_lo: float = 0.5  # band sampled, as multiples of w_p
    omega_hi: float = 3.5
    force_factor: tuple[float, float, float] = (1.0, 1.0, 1.0)  # on [X, Y, N]

    @property
    def enabled(self) -> bool:
        return self.hs_m > 0.0


def _sinc(u: FloatArray) -> FloatArray:
    out: FloatArray = np.sinc(u / math.pi)  # sin(u) / u
    return out


def _first_moment(q: FloatArray, length: float) -> FloatArray:
    """d/dq of integral_{-l/2}^{l/2} e^{-iqs} ds = l sinc(q l / 2), i.e. -i * int s e^{-iqs}."""
    h = 0.5 * length
    small = np.abs(q * h) < 1e-4
    qs = np.where(small, 1.0, q)
    exact = (length * np.cos(qs * h) - 2.0 * np.sin(qs * h) / qs) / qs
    out: FloatArray = np.where(small, -q * length**3 / 12.0, exact)
    return out


def froude_krylov(k: FloatArray, chi_rad: float, hull: HullGeometry) -> FloatArray:
    """Complex force per metre of wave amplitude (n, 3) on a box L x B x T, for waves of
    wave number k (n,) travelling at chi = beta - psi in the body frame (rad)::

        F_x = rho g Z I0(k_y, B) 2i sin(k_x L / 2),   F_y = rho g Z I0(k_x, L) 2i sin(k_y B / 2)
        N   = rho g Z [I1(k_x, L) 2i sin(k_y B / 2) - I1(k_y, B) 2i sin(k_x L / 2)]

    Z = (1 - e^{-kT}) / k, I0(q, l) = l sinc(q l / 2), I1(q, l) = i dI0/dq, all times
    C_B; the force of a component of elevation a cos(theta) at CO is Re{a F e^{i theta}}.
    Long waves (kL -> 0): F_x -> i rho C_B L B T w^2, the displaced mass times the
    water's acceleration."""
    kx, ky = k * math.cos(chi_rad), k * math.sin(chi_rad)
    length, beam = hull.l_oa_m, hull.beam_m
    z = -np.expm1(-k * hull.draft_m) / k
    scale = hull.block_coefficient * hull.rho_water_kg_m3 * G_M_S2 * z
    sx, sy = 2j * np.sin(0.5 * kx * length), 2j * np.sin(0.5 * ky * beam)
    fx = scale * beam * _sinc(0.5 * ky * beam) * sx
    fy = scale * length * _sinc(0.5 * kx * length) * sy
    n = scale * 1j * (_first_moment(kx, length) * sy - _first_moment(ky, beam) * sx)
    return np.stack([fx, fy, n], axis=-1)


@dataclass(frozen=True)
class WaveComponents:
    """Sampled long-crested sea: amplitudes (m), frequencies (rad/s), wave numbers (rad/m),
    phases (rad) and the direction the waves travel to (rad, NED)."""

    amplitude_m: FloatArray
    omega_rad_s: FloatArray
    k_rad_m: FloatArray
    phase_rad: FloatArray
    direction_rad: float
    force_factor: tuple[float, float, float] = (1.0, 1.0, 1.0)

    @classmethod
    def sample(cls, cfg: WaveConfig, rng: np.random.Generator) -> WaveComponents:
        """One frequency per equal-width bin of [omega_lo, omega_hi] w_p, uniform inside
        its bin (no repetition period); a_i = sqrt(2 S(w_i) dw)."""
        wp = 2.0 * math.pi / cfg.tp_s
        edges = np.linspace(cfg.omega_lo * wp, cfg.omega_hi * wp, cfg.n_components + 1)
        w = rng.uniform(edges[:-1], edges[1:])
        a = np.sqrt(2.0 * jonswap(w, cfg.hs_m, cfg.tp_s, cfg.gamma) * np.diff(edges))
        phase = rng.uniform(0.0, 2.0 * math.pi, cfg.n_components)
        return cls(a, w, w**2 / G_M_S2, phase, cfg.direction_rad, cfg.force_factor)

    def phases(self, t_s: float | FloatArray, x: FloatArray) -> FloatArray:
        """theta_i at CO (..., n): w t - k (N cos beta + E sin beta) + phi."""
        along = x[0] * math.cos(self.direction_rad) + x[1] * math.sin(self.direction_rad)
        t = np.asarray(t_s, dtype=np.float64)
        out: FloatArray = np.multiply.outer(t, self.omega_rad_s) - self.k_rad_m * along
        return out + self.phase_rad

    def elevation(self, t_s: float | FloatArray, x: FloatArray) -> FloatArray:
        """Wave elevation at CO (m), positive up."""
        out: FloatArray = np.cos(self.phases(t_s, x)) @ self.amplitude_m
        return out

    def wrench(self, t_s: float | FloatArray, x: FloatArray, hull: HullGeometry) -> FloatArray:
        """First-order (Froude-Krylov) body wrench (..., 3) at heading x[2]:
        Re{a_i F_i e^{i theta_i}} summed, in real arithmetic (F_x, F_y are imaginary and N
        is real for the box, ``froude_krylov``), twice as fast as the complex form."""
        gx, gy, gn = self._transfer(self.direction_rad - float(x[2]), hull)
        theta = self.phases(t_s, x)
        sin = np.sin(theta)
        return np.stack([-(sin @ gx), -(sin @ gy), np.cos(theta) @ gn], axis=-1)

    def _transfer(
        self, chi_rad: float, hull: HullGeometry
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Im F_x, Im F_y, Re N of ``froude_krylov`` times amplitude and force_factor."""
        k, length, beam = self.k_rad_m, hull.l_oa_m, hull.beam_m
        ax, ay = 0.5 * length * k * math.cos(chi_rad), 0.5 * beam * k * math.sin(chi_rad)
        sx, sy, cx, cy = np.sin(ax), np.sin(ay), np.cos(ax), np.cos(ay)
        scale = (2.0 * hull.block_coefficient * hull.rho_water_kg_m3 * G_M_S2) * self.amplitude_m
        scale = scale * -np.expm1(-k * hull.draft_m) / k
        fx, fy, fn = self.force_factor
        gx = fx * scale * beam * _ratio(sy, ay) * sx
        gy = fy * scale * length * _ratio(sx, ax) * sy
        gn = -fn * scale * (_moment(sx, cx, ax, length) * sy - _moment(sy, cy, ay, beam) * sx)
        return gx, gy, gn


def _ratio(sin_a: FloatArray, a: FloatArray) -> FloatArray:
    """sin(a) / a, 1 at a = 0."""
    small = np.abs(a) < 1e-8
    out: FloatArray = np.where(small, 1.0, sin_a / np.where(small, 1.0, a))
    return out


def _moment(sin_a: FloatArray, cos_a: FloatArray, a: FloatArray, length: float) -> FloatArray:
    """dI0/dq at q = 2 a / l: l^2 (cos a - sin a / a) / (2 a), -l^2 a / 6 near a = 0."""
    small = np.abs(a) < 1e-4
    safe = np.where(small, 1.0, a)
    exact = length**2 * (cos_a - sin_a / safe) / (2.0 * safe)
    out: FloatArray = np.where(small, -(length**2) * a / 6.0, exact)
    return out
