"""Scenario files (TOML): plant, thrusters, reference, faults, controller, allocator settings.

The format is documented in ``docs/scenarios.md``; shipped files live in
``ftcap_hil/data/scenarios``. Every error names the offending key and value.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.core.allocator import AllocatorConfig
from ftcap_hil.core.controllers import PoseController, StateFeedback
from ftcap_hil.core.cycle import CoreConfig, Mode, Truth
from ftcap_hil.core.estimator import EstimatorConfig
from ftcap_hil.core.excitation import ExcitationConfig
from ftcap_hil.core.geometry import (
    ConfigError,
    Thruster,
    ThrusterSet,
    effectiveness,
    thrusters_from_table,
)
from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.plants import LinearPlant, SurfaceVessel


@dataclass(frozen=True)
class Segment:
    """A value that holds from ``start`` (inclusive) until the next segment."""

    start: float
    value: FloatArray


@dataclass(frozen=True)
class FaultEvent:
    """From ``start`` (inclusive) until ``end`` (exclusive; inf = forever): either one thruster
    (``thruster`` 0-based, scalar delta/bias) or all (vectors). Later events override."""

    start: float
    end: float
    thruster: int | None
    delta: FloatArray | None
    bias: FloatArray | None


@dataclass(frozen=True)
class FaultSchedule:
    m: int
    events: tuple[FaultEvent, ...] = ()

    def at(self, t: float) -> Truth:
        delta, f = np.ones(self.m), np.zeros(self.m)
        for ev in self.events:
            if not ev.start <= t < ev.end:
                continue
            sel = slice(None) if ev.thruster is None else ev.thruster
            if ev.delta is not None:
                delta[sel] = ev.delta
            if ev.bias is not None:
                f[sel] = ev.bias
        return Truth(delta, f)

    def change_times(self) -> list[float]:
        times = {ev.start for ev in self.events} | {
            ev.end for ev in self.events if math.isfinite(ev.end)
        }
        return sorted(times)


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    plant: LinearPlant | SurfaceVessel
    thrusters: ThrusterSet
    B: FloatArray  # (k, m)
    dt_s: float
    duration_s: float
    x0: FloatArray
    controller: StateFeedback | PoseController
    reference: tuple[Segment, ...]
    faults: FaultSchedule
    core: CoreConfig
    integrator: str = "euler"  # truth: "euler" (= the allocator's model) or "rk4"
    rk4_substeps: int = 8
    noise_std: FloatArray = field(default_factory=lambda: np.zeros(0))
    seed: int = 0
    time_unit: str = "s"  # "step" for the discrete linear plant

    @property
    def steps(self) -> int:
        return int(round(self.duration_s / self.dt_s))

    def reference_at(self, t: float) -> FloatArray:
        value = self.reference[0].value
        for seg in self.reference:
            if seg.start <= t:
                value = seg.value
        return value

    def phases(self) -> list[tuple[float, float]]:
        """Fault phases [start, end) covering the run, split at every fault change."""
        cuts = [t for t in self.faults.change_times() if 0.0 < t < self.duration_s]
        bounds = [0.0, *cuts, self.duration_s]
        return list(zip(bounds[:-1], bounds[1:], strict=True))

    def with_mode(self, mode: Mode) -> Scenario:
        return replace(self, core=replace(self.core, mode=mode))


def _get(table: dict[str, Any], key: str, where: str, default: Any = ...) -> Any:
    if key in table:
        return table[key]
    if default is ...:
        raise ConfigError(f"{where}.{key}: missing")
    return default


def _float(table: dict[str, Any], key: str, where: str, default: Any = ...) -> float:
    v = _get(table, key, where, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"{where}.{key}: expected a finite number, got {v!r}")
    return float(v)


def _vector(v: Any, where: str, length: int | None = None) -> FloatArray:
    try:
        arr = np.atleast_1d(np.asarray(v, dtype=np.float64))
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected numbers, got {v!r}") from None
    if arr.ndim != 1 or (length is not None and arr.size != length) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{where}: expected {length or 'some'} finite numbers, got {v!r}")
    return arr


def dataclass_from_table(cls: type, table: dict[str, Any], where: str, **extra: Any) -> Any:
    known = {f.name for f in fields(cls)}
    unknown = set(table) - known
    if unknown:
        raise ConfigError(f"{where}: unknown keys {sorted(unknown)} (known: {sorted(known)})")
    try:
        return cls(**{**table, **extra})
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: {e}") from e


def plant_from_tables(
    data: dict[str, Any], where: str
) -> tuple[LinearPlant | SurfaceVessel, ThrusterSet, FloatArray]:
    plant_t = _get(data, "plant", where)
    kind = _get(plant_t, "kind", f"{where}.plant")
    if kind == "linear":
        a = _float(plant_t, "a", f"{where}.plant", 1.2)
        b_v = _float(plant_t, "b_v", f"{where}.plant", 1.0)
        b_u = _vector(_get(plant_t, "b_u", f"{where}.plant"), f"{where}.plant.b_u")
        act = _get(data, "actuators", where)
        lo, hi = (
            _float(act, "u_min", f"{where}.actuators"),
            _float(act, "u_max", f"{where}.actuators"),
        )
        step = _float(act, "step_max", f"{where}.actuators", math.inf)
        ths = ThrusterSet(
            tuple(
                Thruster(
                    f"U{i + 1}",
                    0.0,
                    0.0,
                    0.0,
                    lo,
                    hi,
                    step_max=step if math.isfinite(step) else None,
                )
                for i in range(b_u.size)
            )
        )
        return LinearPlant(a=a, b_v=b_v), ths, b_u[None, :]
    if kind == "vessel":
        params: dict[str, Any] = {
            k: _float(plant_t, k, f"{where}.plant")
            for k in plant_t
            if k not in ("kind", "inversion")
        }
        if "inversion" in plant_t:
            params["inversion"] = plant_t["inversion"]
        vessel = dataclass_from_table(SurfaceVessel, params, f"{where}.plant")
        ths = thrusters_from_table(_get(data, "vessel", where), f"{where}.vessel")
        return vessel, ths, effectiveness(ths)
    raise ConfigError(f"{where}.plant.kind: expected 'linear' or 'vessel', got {kind!r}")


def _faults(entries: list[dict[str, Any]], m: int, where: str) -> FaultSchedule:
    events = []
    for i, ev in enumerate(entries):
        w = f"{where}.fault[{i}]"
        thr = ev.get("thruster")
        if thr is not None and not (isinstance(thr, int) and 1 <= thr <= m):
            raise ConfigError(f"{w}.thruster: expected 1..{m} (1-based), got {thr!r}")
        size = 1 if thr is not None else m
        delta = _vector(ev["delta"], f"{w}.delta", size) if "delta" in ev else None
        bias = _vector(ev["bias"], f"{w}.bias", size) if "bias" in ev else None
        if delta is not None and np.any((delta < 0) | (delta > 1)):
            raise ConfigError(f"{w}.delta: must lie in [0, 1], got {ev['delta']!r}")
        events.append(
            FaultEvent(
                _float(ev, "from", w),
                _float(ev, "until", w) if "until" in ev else math.inf,
                None if thr is None else thr - 1,
                None if delta is None else (delta[0] if thr is not None else delta),
                None if bias is None else (bias[0] if thr is not None else bias),
            )
        )
    return FaultSchedule(m, tuple(events))


def parse_scenario(data: dict[str, Any], where: str = "scenario") -> Scenario:
    head = _get(data, "scenario", where)
    plant, ths, B = plant_from_tables(data, where)
    k = B.shape[0]
    ctl_t = data.get("controller", {})
    if isinstance(plant, LinearPlant):
        controller: StateFeedback | PoseController = StateFeedback(
            gain=_float(ctl_t, "K", f"{where}.controller", -0.6), a=plant.a, b_v=plant.b_v
        )
        ref_len, x_len, unit = 1, 1, "step"
    else:
        controller = PoseController(
            kp=_float(ctl_t, "kp", f"{where}.controller", 0.75),
            k_eta=_float(ctl_t, "k_eta", f"{where}.controller", 0.63),
        )
        ref_len, x_len, unit = 3, 6, "s"
    refs = _get(data, "reference", where)
    reference = tuple(
        Segment(
            _float(r, "from", f"{where}.reference[{i}]"),
            _vector(
                _get(r, "value", f"{where}.reference[{i}]"),
                f"{where}.reference[{i}].value",
                ref_len,
            ),
        )
        for i, r in enumerate(refs)
    )
    mode_name = head.get("mode", "ftcap")
    try:
        mode = Mode(mode_name)
    except ValueError:
        raise ConfigError(
            f"{where}.scenario.mode: {mode_name!r} not one of {[m.value for m in Mode]}"
        ) from None
    core = CoreConfig(
        mode=mode,
        estimator=dataclass_from_table(
            EstimatorConfig,
            # a discrete-time plant has no sample straddling an onset (faults act per step)
            {"evict_straddling": not isinstance(plant, LinearPlant), **data.get("estimator", {})},
            f"{where}.estimator",
        ),
        allocator=dataclass_from_table(
            AllocatorConfig, data.get("allocator", {}), f"{where}.allocator"
        ),
        excitation=dataclass_from_table(
            ExcitationConfig, data.get("excitation", {}), f"{where}.excitation"
        ),
    )
    noise = data.get("noise", {}).get("state_std")
    integrator = head.get("integrator", "euler")
    if integrator not in ("euler", "rk4"):
        raise ConfigError(
            f"{where}.scenario.integrator: expected 'euler' or 'rk4', got {integrator!r}"
        )
    x0 = _vector(head.get("x0", [0.0] * x_len), f"{where}.scenario.x0", x_len)
    dt = _float(head, "dt", f"{where}.scenario", 1.0 if unit == "step" else math.nan)
    if not dt > 0:
        raise ConfigError(f"{where}.scenario.dt: must be > 0, got {dt}")
    sc = Scenario(
        name=str(head.get("name", where)),
        description=str(head.get("description", "")),
        plant=plant,
        thrusters=ths,
        B=B,
        dt_s=dt,
        duration_s=_float(head, "duration", f"{where}.scenario"),
        x0=x0,
        controller=controller,
        reference=reference,
        faults=_faults(data.get("fault", []), ths.m, where),
        core=core,
        integrator=integrator,
        rk4_substeps=int(head.get("rk4_substeps", 8)),
        noise_std=np.zeros(x_len)
        if noise is None
        else _vector(noise, f"{where}.noise.state_std", x_len),
        seed=int(head.get("seed", 0)),
        time_unit=unit,
    )
    if k != ref_len:
        raise ConfigError(f"{where}: B has {k} rows but the plant has {ref_len} virtual inputs")
    return sc


SHIPPED = "ftcap_hil.data.scenarios"


def shipped_scenarios() -> list[str]:
    return sorted(
        p.name[:-5] for p in resources.files(SHIPPED).iterdir() if p.name.endswith(".toml")
    )


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A path to a TOML file, or the name of a shipped scenario (``paper-4.2-ex1``)."""
    path = Path(name_or_path)
    if path.exists():
        text = path.read_bytes()
        where = str(path)
    elif str(name_or_path) in shipped_scenarios():
        text = resources.files(SHIPPED).joinpath(f"{name_or_path}.toml").read_bytes()
        where = str(name_or_path)
    else:
        raise ConfigError(
            f"scenario {str(name_or_path)!r}: no such file or shipped scenario"
            f" {shipped_scenarios()}"
        )
    try:
        data = tomllib.loads(text.decode())
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{where}: {e}") from e
    return parse_scenario(data, where)
