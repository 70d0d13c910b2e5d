"""From a campaign file to its runs: one scenario document per run, and its replay file.

A *case* is one scenario entry x seed x fault draw (or a healthy run); its runs are the
fault-free ``none`` reference, CAP and the oracle (the deviation references; left out of
healthy cases, where both are the ``none`` run exactly) and every other mode or variant.
Each run is a full scenario document: the file, the entry's ``[scenario.set]`` tables
deep-merged in, the duration, ``[scenario] seed`` = the campaign seed (the noise draws),
the faults (as in the file, generated, or none), and the variant's tables. The same document
is written to ``DIR/replay/`` so ``ftcap-hil simulate`` reproduces the run; a relative
``[plant] preset`` path in it is made absolute against the file that names it (the
scenario file, or the campaign file for a ``[scenario.set]`` one), so a replay reads the
same preset from any working directory.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import re
import shlex
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ftcap_hil.config.campaign import CampaignSpec, FaultSource, ScenarioEntry, Variant
from ftcap_hil.config.realistic import anchor_preset
from ftcap_hil.config.scenario import SHIPPED, parse_scenario
from ftcap_hil.config.toml import read_toml
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.faults import EventKind
from ftcap_hil.core.scenario import Scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.report.campaign_metrics import classify
from ftcap_hil.runtime.campaign import CampaignPlan, RunTask
from ftcap_hil.runtime.campaign_faults import random_faults

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")
FROZEN = "frozen"  # the kind of a thruster whose output is frozen ([[fault]] kind = "stuck")
# Scenario-file faults whose time profile is their kind (a ramp is no step to "partial")
NAMED_EVENTS = {EventKind.RAMP: "ramp", EventKind.INTERMITTENT: "intermittent"}


def deep_merge(base: dict[str, Any], top: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``top`` merged in: tables recursively, anything else replaced."""
    out = copy.deepcopy(base)
    for key, value in top.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _key(k: str) -> str:
    return k if _BARE_KEY.match(k) else json.dumps(k)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return ("-inf" if v < 0 else "inf") if math.isinf(v) else "nan" if v != v else repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise ValueError(f"cannot write {v!r} ({type(v).__name__}) as TOML")


def _is_table_list(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def _emit(table: dict[str, Any], path: list[str], header: str | None, out: list[str]) -> None:
    if header is not None:
        out += ["", header]
    nested = {k: v for k, v in table.items() if isinstance(v, dict) or _is_table_list(v)}
    out += [f"{_key(k)} = {_value(v)}" for k, v in table.items() if k not in nested]
    for k, v in nested.items():
        sub = ".".join(_key(p) for p in [*path, k])
        if isinstance(v, dict):
            _emit(v, [*path, k], f"[{sub}]", out)
        else:
            for item in v:
                _emit(item, [*path, k], f"[[{sub}]]", out)


def dumps_toml(doc: dict[str, Any]) -> str:
    """A TOML document (tables, arrays of tables, numbers, strings, lists) as text that
    ``tomllib`` reads back equal; floats are written with ``repr`` (exact)."""
    out: list[str] = []
    _emit(doc, [], None, out)
    return "\n".join(out).lstrip("\n") + "\n"


@dataclass(frozen=True)
class Case:
    name: str
    label: str
    seed: int
    healthy: bool
    kind: str
    doc: dict[str, Any]
    fault_kinds: tuple[tuple[int, str], ...]
    length_m: float


def _read(entry: ScenarioEntry, spec: CampaignSpec) -> dict[str, Any]:
    source: str | Path = entry.source
    if spec.base is not None and not Path(source).is_absolute():
        if (spec.base / source).is_file():
            source = spec.base / source
    file = read_toml(source, SHIPPED, what="scenario")
    # a relative preset path: to the scenario file, or to the campaign file for [scenario.set]
    data = anchor_preset(file.data, file.base)
    doc = deep_merge(data, anchor_preset(entry.overrides, spec.base))
    doc.setdefault("scenario", {})
    duration = entry.duration_s or spec.duration_s
    if duration is not None:
        doc["scenario"]["duration"] = duration
    return doc


def _length(sc: Scenario, given: float | None) -> float:
    """The vessel's length for the harm floor: given, the plant's, or the thrusters' extent."""
    if given is not None:
        return given
    length = getattr(sc.plant, "length_m", None)
    if isinstance(length, float):
        return length
    xs = [t.x_m for t in sc.thrusters.thrusters]
    return float(max(xs) - min(xs))


def schedule_kinds(sc: Scenario) -> dict[int, str]:
    """The kind of each faulty thruster in a scenario's own schedule: ``frozen`` for an
    output frozen at its onset value (``kind = "stuck"``: the schedule flags it, delta 1 and
    f 0 stay nominal), the kind the file names for a ``ramp`` or ``intermittent`` fault, the
    metrics' ``classify`` of delta and f for every other fault, and ``mixed`` for a thruster
    with faults of several of these kinds."""
    times = [t for t in sc.faults.change_times() if t < sc.duration_s]
    truths = [sc.faults.at(t) for t in times]
    out = {}
    for i in range(sc.thrusters.m):
        frozen = any(tr.stuck[i] for tr in truths)
        named = {
            NAMED_EVENTS[e.kind]
            for e in sc.faults.events
            if e.kind in NAMED_EVENTS and e.thruster in (None, i) and e.start < sc.duration_s
        }
        other = [tr for tr in truths if not tr.stuck[i] and (tr.delta[i] != 1 or tr.f[i] != 0)]
        if other:
            kind = classify(np.array([tr.delta[i] for tr in other]),
                            np.array([tr.f[i] for tr in other]))  # fmt: skip
            if named:
                kind = named.pop() if len(named) == 1 else "mixed"
            out[i] = "mixed" if frozen else kind
        elif frozen:
            out[i] = FROZEN
    return out


def _run_kind(kinds: dict[int, str]) -> str:
    found = set(kinds.values())
    return "healthy" if not found else found.pop() if len(found) == 1 else "multi"


def _with(doc: dict[str, Any], seed: int, faults: list[dict[str, Any]] | None) -> dict[str, Any]:
    out = copy.deepcopy(doc)
    out["scenario"]["seed"] = seed
    if faults is not None:
        out.pop("fault", None)
        if faults:
            out["fault"] = faults
    return out


def _random_cases(
    entry: ScenarioEntry, spec: CampaignSpec, doc: dict[str, Any], sc: Scenario, seed: int
) -> list[Case]:
    """The cases of one seed with generated faults: one per kind, or one drawing the kind."""
    u_range = np.maximum(np.abs(sc.thrusters.u_min), np.abs(sc.thrusters.u_max))
    length = _length(sc, entry.length_m)
    cases = []
    for kind in spec.faults.kinds if spec.faults.each_kind else (None,):
        label = "" if kind is None else kind.value
        salt = [seed, zlib.crc32(entry.label.encode()), zlib.crc32(label.encode())]
        try:
            rng = np.random.default_rng(salt)
            gen = random_faults(rng, u_range, sc.duration_s, spec.faults, kind)
        except ValueError as e:
            raise ConfigError(f"{spec.source}: scenario {entry.label}: {e}") from e
        kinds = {g.thruster: g.label for g in gen}
        tables = [t for g in gen for t in g.tables]
        name = f"{entry.label}/s{seed}" + (f"/{label}" if label else "")
        cases.append(Case(name, entry.label, seed, False, _run_kind(kinds),
                          _with(doc, seed, tables), tuple(kinds.items()), length))  # fmt: skip
    return cases


def _entry_cases(entry: ScenarioEntry, spec: CampaignSpec) -> list[Case]:
    """The cases of one ``[[scenario]]``: per seed, its faults as the entry says."""
    doc = _read(entry, spec)
    sc = parse_scenario(doc, f"{spec.source}: scenario {entry.label}")
    length = _length(sc, entry.length_m)
    kinds = schedule_kinds(sc)
    cases = []
    for seed in spec.seeds:
        name = f"{entry.label}/s{seed}"
        if entry.faults is FaultSource.SCENARIO:
            cases.append(Case(name, entry.label, seed, False, _run_kind(kinds),
                              _with(doc, seed, None), tuple(kinds.items()), length))  # fmt: skip
        elif entry.faults is FaultSource.NONE:
            healthy = _with(doc, seed, [])
            cases.append(Case(name, entry.label, seed, True, "healthy", healthy, (), length))
        else:
            cases += _random_cases(entry, spec, doc, sc, seed)
    return cases


def _healthy_cases(spec: CampaignSpec) -> list[Case]:
    h = spec.healthy
    if h is None:
        return []
    out = []
    for entry in spec.scenarios:
        if h.scenarios is not None and entry.label not in h.scenarios:
            continue
        doc = _read(entry, spec)
        if h.duration_s is not None:
            doc["scenario"]["duration"] = h.duration_s
        length = _length(
            parse_scenario(doc, f"{spec.source}: healthy {entry.label}"), entry.length_m
        )
        for seed in h.seeds:
            out.append(
                Case(
                    f"{entry.label}/healthy/s{seed}",
                    entry.label,
                    seed,
                    True,
                    "healthy",
                    _with(doc, seed, []),
                    (),
                    length,
                )
            )
    return out


def _safe(name: str) -> str:
    return name.replace("/", "-")


def _replay_name(case: Case, variant: Variant) -> str:
    return _safe(case.name) + (f"--{variant.name}" if variant.tables else "") + ".toml"


def _task(case: Case, variant: Variant, spec: CampaignSpec, out_dir: Path) -> tuple[RunTask, dict]:
    doc = deep_merge(case.doc, variant.tables)
    doc["scenario"]["mode"] = variant.mode.value
    key = f"{case.name}/{variant.name}"
    sc = parse_scenario(doc, f"{spec.source}: run {key}")
    digest = hashlib.sha256(
        json.dumps([doc, variant.mode.value], sort_keys=True).encode()
    ).hexdigest()[:16]
    file = out_dir / "replay" / _replay_name(case, variant)
    cmd = shlex.join(
        [
            "ftcap-hil",
            "simulate",
            str(file),
            "--mode",
            variant.mode.value,
            "--out",
            str(out_dir / "replay-out" / _safe(key)),
            "--mcap",  # the replay's run.mcap, to look at the run in Foxglove
        ]
    )
    task = RunTask(
        key,
        digest,
        case.name,
        variant.name,
        variant.mode,
        sc,
        case.label,
        case.seed,
        case.healthy,
        case.kind,
        case.length_m,
        cmd,
        case.fault_kinds,
    )
    return task, doc


NONE = Variant("none", Mode.NONE, {})


def plan_campaign(spec: CampaignSpec, out_dir: Path) -> tuple[CampaignPlan, dict[str, str]]:
    """The plan and its replay files (name in ``DIR/replay`` -> TOML text)."""
    cases = [c for e in spec.scenarios for c in _entry_cases(e, spec)] + _healthy_cases(spec)
    tasks, files = [], {}
    for case in cases:
        for variant in (NONE, *spec.variants):
            if case.healthy and variant.name in ("cap", "oracle"):
                continue  # identical to the none run without faults
            task, doc = _task(case, variant, spec, out_dir)
            tasks.append(task)
            name = _replay_name(case, variant)
            if name not in files:
                head = (
                    f"# campaign {spec.name}, case {case.name}: replay a run with\n"
                    f"#   ftcap-hil simulate THIS_FILE --mode MODE --out DIR --mcap\n"
                    "# (runs.csv has the exact command of every run)\n"
                )
                files[name] = head + dumps_toml(doc if variant.tables else case.doc)
    return CampaignPlan(spec.name, tuple(tasks), spec.metrics), files
