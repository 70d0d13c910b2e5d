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
* Waves: long-crested, N components sampled from a JONSWAP spectrum (DNV-RP-C205 3.5.5,
  gamma = 1 gives Pierson-Moskowitz) on [w_lo, w_hi] x w_p, deep water (k = w^2/g). The
  force is the Froude-Krylov force on a box L x B x T (``froude_krylov``): the undisturbed
  wave pressure integrated over the hull, which falls off for waves short against the hull
  (sinc of k L / 2) or deep against the draft (e^{kz}). Simplified: no diffraction, no
  radiation damping, no second-order (mean drift) forces, no spreading. ``force_factor``
  (per axis, default 1) stands in for the diffraction part: in waves long against the
  hull the total first-order force is (rho nabla + A) times the water's acceleration
  (G. I. Taylor's long-wave limit), i.e. the Froude-Krylov force times 1 + A / (rho nabla)
  (docs/vessels.md compares the result with ShipX force RAOs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ftcap_hil.core.messages import FloatArray

G_M_S2 = 9.81
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
