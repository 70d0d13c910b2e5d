"""The vessel's environment: ocean current, wind, first-order waves (pure, seeded).

Every component is off by default (all levels zero) and, when on, is a sum of sinusoids
with random frequencies and phases drawn once from its own seeded stream, so its value at
time t is a pure function of t and the seed: the same whatever step size or shell asks,
and switching one component on does not change another's realisation. Conventions
(Fossen, Handbook of Marine Craft Hydrodynamics and Motion Control, 2021, ch. 10):
directions are where the current, the wind and the waves go *to*, clockwise from north
(rad); the wrench is body frame [X (N), Y (N), N (N m)].

* Current (Fossen 2021 ch. 10.3): V_c(t) = max(0, V + dV(t)), beta_c(t) = beta + dbeta(t);
  dV, dbeta are zero-mean processes with the spectrum of a first-order Gauss-Markov
  process (time constant tau, stationary std sigma): S(w) = 2 sigma^2 tau / (pi (1 +
  w^2 tau^2)) on w >= 0. Output in NED, [V_c cos beta_c, V_c sin beta_c]; the plant turns
  it into the relative velocity nu_r = nu - R(psi)^T v_c.
* Wind (Fossen 2021 ch. 10.1): mean speed plus a Gauss-Markov gust on the speed (the
  direction is held), relative wind from the vessel's velocity, Blendermann's (1994)
  coefficients for C_X, C_Y, C_N (MSS blendermann94.m), scaled by the frontal and lateral
  projected areas A_Fw, A_Lw and L_oa; air density 1.224 kg/m^3 (MSS). Simplified: no roll,
  no gust on the direction, the lateral area's centroid s_L measured from CO.
* Waves: ``sim.waves`` (a sampled JONSWAP sea, the Froude-Krylov force on a box with a
  per-axis diffraction factor). Simplified: no radiation, no second-order (mean drift)
  forces, no spreading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ftcap_hil.core.messages import FloatArray
from sim.waves import G_M_S2, HullGeometry, WaveComponents, WaveConfig, froude_krylov, jonswap

__all__ = [
    "G_M_S2", "RHO_AIR_KG_M3", "CurrentConfig", "Environment", "EnvironmentConfig",
    "EnvironmentSample", "HullGeometry", "SineSum", "WaveComponents", "WaveConfig",
    "WindCoefficients", "WindConfig", "blendermann", "froude_krylov", "gauss_markov_sines",
    "jonswap", "wind_wrench",
]  # fmt: skip

RHO_AIR_KG_M3 = 1.224  # MSS blendermann94.m, "density of air at 20 C"


@dataclass(frozen=True)
class SineSum:
    """x(t) = sum_i a_i cos(w_i t + phi_i); t scalar or (n,) (s) -> scalar or (n,)."""

    amplitude: FloatArray
    omega_rad_s: FloatArray
    phase_rad: FloatArray

    def __call__(self, t_s: float | FloatArray) -> FloatArray:
        arg = np.multiply.outer(np.asarray(t_s, dtype=np.float64), self.omega_rad_s)
        out: FloatArray = np.cos(arg + self.phase_rad) @ self.amplitude
        return out

    @property
    def variance(self) -> float:
        """The time-average variance, sum a_i^2 / 2."""
        return float(0.5 * np.sum(self.amplitude**2))


ZERO_SUM = SineSum(np.zeros(0), np.zeros(0), np.zeros(0))


def gauss_markov_sines(
    std: float, time_constant_s: float, n: int, rng: np.random.Generator
) -> SineSum:
    """A zero-mean process with a first-order Gauss-Markov spectrum and exactly ``std``.

    Frequencies: one per log-spaced bin over [0.01, 100] / tau (98.7 % of the spectrum's
    variance), drawn uniformly in log inside its bin; amplitudes sqrt(2 S(w_i) dw_i), then
    scaled so that sum a^2 / 2 = std^2; phases uniform. Zero std gives the zero process.
    """
    if std == 0.0:
        return ZERO_SUM
    edges = np.geomspace(1e-2, 1e2, n + 1) / time_constant_s
    w = np.exp(rng.uniform(np.log(edges[:-1]), np.log(edges[1:])))
    s = 2.0 * std**2 * time_constant_s / (math.pi * (1.0 + (w * time_constant_s) ** 2))
    a = np.sqrt(2.0 * s * np.diff(edges))
    a *= std / math.sqrt(0.5 * np.sum(a**2))
    return SineSum(a, w, rng.uniform(0.0, 2.0 * math.pi, n))


@dataclass(frozen=True)
class WindCoefficients:
    """Blendermann (1994) coefficients; defaults: "offshore supply vessel" (MSS
    blendermann94.m, row 11): CD_t, CD_l,AF(0), CD_l,AF(pi), delta."""

    cd_t: float = 0.90
    cd_l_bow: float = 0.55
    cd_l_stern: float = 0.80
    delta: float = 0.55


@dataclass(frozen=True)
class CurrentConfig:
    speed_m_s: float = 0.0
    direction_rad: float = 0.0
    speed_std_m_s: float = 0.0
    direction_std_rad: float = 0.0
    time_constant_s: float = 600.0
    n_components: int = 64

    @property
    def enabled(self) -> bool:
        return self.speed_m_s > 0.0 or self.speed_std_m_s > 0.0


@dataclass(frozen=True)
class WindConfig:
    speed_m_s: float = 0.0
    direction_rad: float = 0.0
    gust_std_m_s: float = 0.0
    gust_time_constant_s: float = 30.0
    n_components: int = 64
    coefficients: WindCoefficients = field(default_factory=WindCoefficients)

    @property
    def enabled(self) -> bool:
        return self.speed_m_s > 0.0 or self.gust_std_m_s > 0.0


@dataclass(frozen=True)
class EnvironmentConfig:
    current: CurrentConfig = field(default_factory=CurrentConfig)
    wind: WindConfig = field(default_factory=WindConfig)
    waves: WaveConfig = field(default_factory=WaveConfig)
    seed: int = 0

    def __post_init__(self) -> None:
        for name, value in (
            ("current.speed_m_s", self.current.speed_m_s),
            ("current.speed_std_m_s", self.current.speed_std_m_s),
            ("current.direction_std_rad", self.current.direction_std_rad),
            ("wind.speed_m_s", self.wind.speed_m_s),
            ("wind.gust_std_m_s", self.wind.gust_std_m_s),
            ("waves.hs_m", self.waves.hs_m),
        ):
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name}: must be finite and >= 0, got {value}")
        for name, value in (
            ("current.time_constant_s", self.current.time_constant_s),
            ("wind.gust_time_constant_s", self.wind.gust_time_constant_s),
            ("waves.tp_s", self.waves.tp_s),
            ("waves.gamma", self.waves.gamma),
        ):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name}: must be finite and > 0, got {value}")
        if len(self.waves.force_factor) != 3 or min(self.waves.force_factor) < 0.0:
            raise ValueError("waves.force_factor: expected 3 numbers >= 0")
        if not 0.0 < self.waves.omega_lo < self.waves.omega_hi:
            raise ValueError("waves: need 0 < omega_lo < omega_hi")


def blendermann(gamma_rw: FloatArray, c: WindCoefficients, hull: HullGeometry) -> FloatArray:
    """[C_X, C_Y, C_N] (..., 3) at relative wind angles gamma_rw (rad, 0 = head wind,
    positive = wind from port), Blendermann (1994) as in Fossen (2021) ch. 10.1.2."""
    g = np.asarray(gamma_rw, dtype=np.float64)
    cd_l_af = np.where(np.abs(g) <= 0.5 * math.pi, c.cd_l_bow, c.cd_l_stern)
    cd_l = cd_l_af * hull.a_front_m2 / hull.a_lateral_m2
    den = 1.0 - 0.5 * c.delta * (1.0 - cd_l / c.cd_t) * np.sin(2.0 * g) ** 2
    cx = -cd_l_af * np.cos(g) / den
    cy = c.cd_t * np.sin(g) / den
    cn = (hull.s_l_m / hull.l_oa_m - 0.18 * (np.abs(g) - 0.5 * math.pi)) * cy
    return np.stack([cx, cy, cn], axis=-1)


def wind_wrench(
    wind_ned: FloatArray, x: FloatArray, c: WindCoefficients, hull: HullGeometry
) -> FloatArray:
    """Body wrench (3,) of the wind velocity ``wind_ned`` = [V_N, V_E] (m/s, going to) on
    the vessel in state x: 1/2 rho_a V_rw^2 [C_X A_Fw, C_Y A_Lw, C_N A_Lw L_oa], with
    u_rw = u - u_w, v_rw = v - v_w, gamma_rw = -atan2(v_rw, u_rw)."""
    cs, sn = math.cos(x[2]), math.sin(x[2])
    u_w = cs * wind_ned[0] + sn * wind_ned[1]
    v_w = -sn * wind_ned[0] + cs * wind_ned[1]
    u_rw, v_rw = x[3] - u_w, x[4] - v_w
    q = 0.5 * RHO_AIR_KG_M3 * (u_rw**2 + v_rw**2)
    coef = blendermann(np.array(-math.atan2(v_rw, u_rw)), c, hull)
    area = np.array([hull.a_front_m2, hull.a_lateral_m2, hull.a_lateral_m2 * hull.l_oa_m])
    out: FloatArray = q * coef * area
    return out


@dataclass(frozen=True)
class EnvironmentSample:
    current_ned: FloatArray  # (2,) [V_N, V_E] m/s
    tau_env: FloatArray  # (3,) body wrench of wind and waves
    wave_elevation_m: float


class Environment:
    """Current, wind and waves for one run, all drawn at construction from ``seed``
    (``config.seed`` unless given). Component streams are independent children of it."""

    def __init__(self, config: EnvironmentConfig, hull: HullGeometry, seed: int | None = None):
        self.config, self.hull = config, hull
        streams = np.random.SeedSequence(config.seed if seed is None else seed).spawn(3)
        cur, wind, waves = (np.random.default_rng(s) for s in streams)
        c, w = config.current, config.wind
        n_c = c.n_components
        self._dv = gauss_markov_sines(c.speed_std_m_s, c.time_constant_s, n_c, cur)
        self._dbeta = gauss_markov_sines(c.direction_std_rad, c.time_constant_s, n_c, cur)
        self._gust = gauss_markov_sines(
            w.gust_std_m_s, w.gust_time_constant_s, w.n_components, wind
        )
        self.waves = WaveComponents.sample(config.waves, waves) if config.waves.enabled else None
        if w.enabled and (hull.a_front_m2 <= 0.0 or hull.a_lateral_m2 <= 0.0):
            raise ValueError("wind needs the hull's a_front_m2 and a_lateral_m2 (> 0)")

    @property
    def calm(self) -> bool:
        """True when every component is off: the plant can be stepped without any."""
        c = self.config
        return not (c.current.enabled or c.wind.enabled or c.waves.enabled)

    def current_ned(self, t_s: float | FloatArray) -> FloatArray:
        """Ocean current [V_N, V_E] (m/s) at t: (2,) or (n, 2) for t of shape (n,)."""
        c = self.config.current
        speed = np.maximum(0.0, c.speed_m_s + self._dv(t_s))
        beta = c.direction_rad + self._dbeta(t_s)
        return np.stack([speed * np.cos(beta), speed * np.sin(beta)], axis=-1)

    def wind_speed(self, t_s: float | FloatArray) -> FloatArray:
        """Wind speed (m/s) at t: mean plus gust, never negative."""
        out: FloatArray = np.maximum(0.0, self.config.wind.speed_m_s + self._gust(t_s))
        return out

    def wind_wrench(self, t_s: float, x: FloatArray) -> FloatArray:
        w = self.config.wind
        if not w.enabled:
            return np.zeros(3)
        beta = w.direction_rad
        wind = float(self.wind_speed(t_s)) * np.array([math.cos(beta), math.sin(beta)])
        return wind_wrench(wind, x, w.coefficients, self.hull)

    def wave_wrench(self, t_s: float | FloatArray, x: FloatArray) -> FloatArray:
        if self.waves is None:
            return np.zeros(np.shape(t_s) + (3,))
        return self.waves.wrench(t_s, x, self.hull)

    def wave_elevation(self, t_s: float | FloatArray, x: FloatArray) -> FloatArray:
        if self.waves is None:
            return np.zeros(np.shape(t_s))
        return self.waves.elevation(t_s, x)

    def sample(self, t_s: float, x: FloatArray) -> EnvironmentSample:
        """Everything at time t for the vessel in state x = [N, E, psi, u, v, r]."""
        tau = self.wind_wrench(t_s, x) + self.wave_wrench(t_s, x)
        return EnvironmentSample(self.current_ned(t_s), tau, float(self.wave_elevation(t_s, x)))
