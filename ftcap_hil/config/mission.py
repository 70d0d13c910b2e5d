"""Ground-station missions (TOML): what ``ftcap-hil gcs`` flies and which faults it injects.

A mission names a scenario (a shipped name such as ``paper-4.2-ex1`` or a path, relative to
the mission file) for the reference schedule, the fault schedule, the controller gains and
the control period; any of ``[controller]``, ``[[reference]]`` and ``[[fault]]`` given in the
mission replaces the scenario's table (same syntax as scenario files, docs/scenarios.md)::

    [mission]
    name = "paper-4.2-ex1"
    description = "..."
    scenario = "paper-4.2-ex1"
    duration = 700.0        # s, default: the scenario's duration
    # period = 0.2827       # s, control period T_s, default: the scenario's dt
    # mode = "ftcap"        # set the allocator's FTC_MODE first; default: leave it as it is

    [gcs]                   # all optional
    connect_timeout_s = 20.0     # heartbeats of vessel and allocator, first ODOMETRY
    odometry_timeout_s = 5.0     # no ODOMETRY for this long mid-flight -> abort
    wrench_limit = [1000.0, 1000.0, 1000.0]  # demands beyond are shrunk along their direction
    clear_faults_at_end = true

The fault schedule is the truth recorded in the timeseries; :func:`injection_plan` turns it
into MAV_CMD_INJECT_FAILURE requests (:class:`Injection`) at every change. Pure: no I/O
beyond reading the files.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.config.daemon import apply_overrides
from ftcap_hil.config.scenario import SHIPPED, Scenario, parse_scenario, shipped_scenarios
from ftcap_hil.core.cycle import Mode, Truth
from ftcap_hil.core.geometry import ConfigError
from ftcap_hil.core.messages import FaultKind, FloatArray
from ftcap_hil.core.plants import wrap_angle
from ftcap_hil.report.records import RunRecord, column_names

MISSIONS = "ftcap_hil.data.hil.missions"
MISSION_KEYS = {"name", "description", "scenario", "duration", "period", "mode"}
GCS_KEYS = {"connect_timeout_s", "odometry_timeout_s", "wrench_limit", "clear_faults_at_end"}
REPLACEABLE = ("controller", "reference", "fault")


@dataclass(frozen=True)
class GcsSettings:
    connect_timeout_s: float = 20.0
    odometry_timeout_s: float = 5.0
    wrench_limit: tuple[float, float, float] = (1000.0, 1000.0, 1000.0)  # the allocator's
    clear_faults_at_end: bool = True


@dataclass(frozen=True)
class Mission:
    name: str
    description: str
    scenario: Scenario  # reference, faults (truth), controller; duration_s = the mission's
    period_s: float  # control period T_s
    mode: Mode | None  # None: fly with whatever mode the allocator is in
    gcs: GcsSettings
    source: str

    @property
    def duration_s(self) -> float:
        return self.scenario.duration_s

    def with_duration(self, duration_s: float) -> Mission:
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise ConfigError(f"duration: expected a positive number of seconds, got {duration_s}")
        return replace(self, scenario=replace(self.scenario, duration_s=float(duration_s)))


@dataclass(frozen=True)
class Injection:
    """One MAV_CMD_INJECT_FAILURE: at mission time ``at_s``, ``kind`` on ``thruster``
    (0-based) with ``value`` (delta for WEAK, N for BIAS / STUCK, NaN otherwise)."""

    at_s: float
    thruster: int
    kind: FaultKind
    value: float = math.nan


def shipped_missions() -> list[str]:
    return sorted(
        p.name[:-5] for p in resources.files(MISSIONS).iterdir() if p.name.endswith(".toml")
    )


def _read_toml(text: bytes, where: str) -> dict[str, Any]:
    try:
        return tomllib.loads(text.decode())
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{where}: {e}") from e


def _mission_data(name_or_path: str | Path) -> tuple[dict[str, Any], str, Path | None]:
    path = Path(name_or_path)
    if path.is_file():
        return _read_toml(path.read_bytes(), str(path)), str(path), path.parent
    name = str(name_or_path).removesuffix(".toml")
    if name in shipped_missions():
        text = resources.files(MISSIONS).joinpath(f"{name}.toml").read_bytes()
        return _read_toml(text, name), name, None
    raise ConfigError(
        f"mission {str(name_or_path)!r}: no such file or shipped mission {shipped_missions()}"
    )


def _scenario_data(ref: Any, base: Path | None, where: str) -> tuple[dict[str, Any], str]:
    if not isinstance(ref, str) or not ref:
        raise ConfigError(f"{where}.mission.scenario: expected a name or a path, got {ref!r}")
    candidates = [Path(ref)] if base is None else [base / ref, Path(ref)]
    for path in candidates:
        if path.is_file():
            return _read_toml(path.read_bytes(), str(path)), str(path)
    if ref in shipped_scenarios():
        return _read_toml(resources.files(SHIPPED).joinpath(f"{ref}.toml").read_bytes(), ref), ref
    raise ConfigError(
        f"{where}.mission.scenario: {ref!r} is no file and no shipped scenario"
        f" {shipped_scenarios()}"
    )


def _positive(table: dict[str, Any], key: str, where: str, default: float) -> float:
    v = table.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
        raise ConfigError(f"{where}.{key}: expected a positive number, got {v!r}")
    return float(v)


def _gcs_settings(table: Any, where: str) -> GcsSettings:
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table")
    if unknown := set(table) - GCS_KEYS:
        raise ConfigError(f"{where}: unknown keys {sorted(unknown)} (known: {sorted(GCS_KEYS)})")
    d = GcsSettings()
    limit = table.get("wrench_limit", list(d.wrench_limit))
    arr = np.asarray(limit, dtype=np.float64) if isinstance(limit, list) else np.zeros(0)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)) or not np.all(arr > 0):
        raise ConfigError(f"{where}.wrench_limit: expected 3 positive numbers, got {limit!r}")
    clear = table.get("clear_faults_at_end", d.clear_faults_at_end)
    if not isinstance(clear, bool):
        raise ConfigError(f"{where}.clear_faults_at_end: expected true/false, got {clear!r}")
    return GcsSettings(
        _positive(table, "connect_timeout_s", where, d.connect_timeout_s),
        _positive(table, "odometry_timeout_s", where, d.odometry_timeout_s),
        (float(arr[0]), float(arr[1]), float(arr[2])),
        clear,
    )


def _mode(value: Any, where: str) -> Mode | None:
    if value is None:
        return None
    allowed = [m.value for m in Mode if m is not Mode.ORACLE]
    if value not in allowed:
        raise ConfigError(f"{where}.mission.mode: expected one of {allowed}, got {value!r}")
    return Mode(value)


def parse_mission(data: dict[str, Any], where: str, base: Path | None = None) -> Mission:
    head = data.get("mission")
    if not isinstance(head, dict):
        raise ConfigError(f"{where}.mission: missing table")
    if unknown := set(head) - MISSION_KEYS:
        raise ConfigError(
            f"{where}.mission: unknown keys {sorted(unknown)} (known: {sorted(MISSION_KEYS)})"
        )
    if unknown := set(data) - {"mission", "gcs", *REPLACEABLE}:
        raise ConfigError(f"{where}: unknown tables {sorted(unknown)}")
    sc_data, sc_where = _scenario_data(head.get("scenario"), base, where)
    for key in REPLACEABLE:
        if key in data:
            sc_data[key] = data[key]
    sc = parse_scenario(sc_data, f"{where} (scenario {sc_where})")
    if sc.time_unit != "s":
        raise ConfigError(f"{where}.mission.scenario: {sc_where!r} is not a vessel scenario")
    duration = _positive(head, "duration", f"{where}.mission", sc.duration_s)
    name = str(head.get("name", sc.name))
    return Mission(
        name=name,
        description=str(head.get("description", sc.description)),
        scenario=replace(sc, name=name, duration_s=duration),  # plots and results name it
        period_s=_positive(head, "period", f"{where}.mission", sc.dt_s),
        mode=_mode(head.get("mode"), where),
        gcs=_gcs_settings(data.get("gcs", {}), f"{where}.gcs"),
        source=where,
    )


def load_mission(name_or_path: str | Path, overrides: list[str] | None = None) -> Mission:
    """A mission file or the name of a shipped one, with ``SECTION.KEY=VALUE`` overrides."""
    data, where, base = _mission_data(name_or_path)
    data = apply_overrides(data, overrides or [])
    return parse_mission(data, where, base)


def _transition(
    i: int, at_s: float, before: tuple[float, float], after: tuple[float, float]
) -> list[Injection]:
    """Injections taking thruster i from (delta, f) ``before`` to ``after``. The vessel's
    WEAK clears the bias and BIAS keeps delta, so a weak and biased thruster is WEAK then
    BIAS; delta = 0 with a bias is STUCK at that force."""
    (d0, f0), (d1, f1) = before, after
    if (d1, f1) == (1.0, 0.0):
        return [Injection(at_s, i, FaultKind.OK)]
    if d1 == 0.0:
        return [Injection(at_s, i, FaultKind.OFF if f1 == 0.0 else FaultKind.STUCK,
                          math.nan if f1 == 0.0 else f1)]  # fmt: skip
    out: list[Injection] = []
    if d1 != d0:
        out.append(Injection(at_s, i, FaultKind.WEAK, d1))
    if f1 != 0.0 or (d1 == d0 and f0 != 0.0):
        out.append(Injection(at_s, i, FaultKind.BIAS, f1))
    return out


def injection_plan(sc: Scenario) -> list[Injection]:
    """The injections that reproduce ``sc.faults`` on a healthy vessel, in time order;
    changes at or after ``sc.duration_s`` are left out."""
    m = sc.thrusters.m
    prev = Truth(np.ones(m), np.zeros(m))
    plan: list[Injection] = []
    for t in sc.faults.change_times():
        if t >= sc.duration_s:
            break
        now = sc.faults.at(t)
        for i in range(m):
            before = (float(prev.delta[i]), float(prev.f[i]))
            after = (float(now.delta[i]), float(now.f[i]))
            if before != after:
                plan += _transition(i, t, before, after)
        prev = now
    return plan


def limit_wrench(v: FloatArray, limit: tuple[float, float, float]) -> FloatArray:
    """Shrink ``v`` along its direction so that |v_j| <= limit_j (the allocator drops a
    WRENCH_SETPOINT beyond its wrench limit as malformed)."""
    scale = float(np.max(np.abs(v) / np.asarray(limit)))
    return v / scale if scale > 1.0 else v


class FlightRecorder:
    """The ground station's record of a flight, in ``report.column_names`` order.

    Per cycle: mission time t (s), the pose from ODOMETRY (psi unwrapped), the reference,
    the wrench sent, the allocator's FTCAP_STATUS (``status``: delta_hat, f_hat, flags) and
    ACTUATOR_OUTPUT_STATUS (``u``, N) as last received (None: not yet: NaN), and the true
    faults from the mission's schedule: v_ach = B (delta u + f), bf_hat = B f_hat.
    innovation, window_len, probing and solve_us are not on MAVLink: NaN.
    """

    def __init__(self, mission: Mission) -> None:
        self.sc = mission.scenario
        self.names = column_names(self.sc)
        self.rows: list[FloatArray] = []
        self._psi: float | None = None

    def _unwrapped(self, psi: float) -> float:
        # ODOMETRY carries yaw in (-pi, pi]; the offline record's psi is continuous
        self._psi = psi if self._psi is None else self._psi + float(wrap_angle(psi - self._psi))
        return self._psi

    def add(
        self, t: float, x: FloatArray, ref: FloatArray, v_dem: FloatArray, status: Any, u: Any
    ) -> None:
        sc, m = self.sc, self.sc.thrusters.m
        truth = sc.faults.at(t)
        nan_m = np.full(m, math.nan)
        u_arr = np.asarray(u, dtype=np.float64) if u is not None and len(u) == m else nan_m
        produced = truth.delta * u_arr + truth.f
        dh = status.delta_hat if status is not None and len(status.delta_hat) == m else nan_m
        fh = status.f_hat if status is not None and len(status.f_hat) == m else nan_m
        degraded = 0.0 if status is None else float(bool(status.flags & 1))  # DEGRADED
        pose = np.array([x[0], x[1], self._unwrapped(float(x[2])), *x[3:]])
        row = np.concatenate(
            [
                [t],
                pose,
                ref,
                v_dem,
                sc.B @ produced,
                u_arr,
                produced,
                truth.delta,
                truth.f,
                dh,
                fh,
                sc.B @ fh,
                [math.nan, math.nan, degraded, math.nan, math.nan],
            ]
        )
        assert row.size == len(self.names)
        self.rows.append(row)

    def finish(self, mode: str, period_s: float, **meta: Any) -> RunRecord:
        """The record; a flight cut short gets a scenario that ends where the flight did."""
        data = np.vstack(self.rows) if self.rows else np.zeros((0, len(self.names)))
        sc = self.sc.with_mode(Mode(mode)) if mode in {m.value for m in Mode} else self.sc
        if self.rows and data[-1, 0] + period_s < sc.duration_s:
            sc = replace(sc, duration_s=float(data[-1, 0] + period_s))
        return RunRecord(sc, mode, {n: data[:, i] for i, n in enumerate(self.names)}, meta)


def summary_lines(res: dict[str, Any]) -> list[str]:
    """Text summary of a results.json: per mode, per fault phase."""
    lines = [f"{res['scenario']}: {len(res['phases'])} phases"]
    for mode, r in res["modes"].items():
        lines.append(
            f"  mode {mode}: bounded {r['bounded']}, {r.get('cycles', '?')} cycles, "
            f"{r.get('overruns', '?')} overruns"
        )
        for p in r["phases"]:
            dh = " ".join(
                "-" if e is None or not math.isfinite(e) else f"{e:.3f}"
                for e in p["delta_error_final"]
            )
            lines.append(
                f"    [{p['start']:6.1f}, {p['end']:6.1f}) s  tracking rms {p['tracking_rms']:.3f}"
                f" max {p['tracking_max']:.3f} m  heading rms {p.get('heading_rms', math.nan):.3f}"
                f" rad  |delta_hat - delta| at end {dh}"
            )
    return lines
