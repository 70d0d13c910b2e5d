"""Campaign files (TOML): scenarios x seeds x modes, fault generation, healthy runs, metrics.

The format is documented in ``docs/campaigns.md``; shipped files live in
``ftcap_hil/data/campaigns``. Every table is strict: an unknown key is an error that names
the file, the table, the key and the nearest valid key. What a scenario override or a
variant sets is checked by the scenario reader when the plan is built.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from ftcap_hil.config.toml import read_toml
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.status import Mode
from ftcap_hil.report.campaign_metrics import MetricParams

SHIPPED = "ftcap_hil.data.campaigns"
FAULT_KINDS = ("dead", "stuck", "partial", "bias", "intermittent")
PLAIN_MODES = {m.value: m for m in Mode if m is not Mode.NONE}
VARIANT_TABLES = ("estimator", "excitation", "allocator")
FAULT_SOURCES = ("scenario", "random", "none")
Range = tuple[float, float]


@dataclass(frozen=True)
class ScenarioEntry:
    """One ``[[scenario]]``: a scenario file (path or shipped name) and what changes in it."""

    source: str
    label: str
    faults: str  # "scenario" (as in the file), "random" (from [faults]) or "none"
    overrides: dict[str, Any]  # deep-merged into the scenario document ([scenario.set])
    duration_s: float | None
    length_m: float | None


@dataclass(frozen=True)
class Variant:
    """A mode under a name, with estimator / excitation / allocator tables merged in."""

    name: str
    mode: Mode
    tables: dict[str, dict[str, Any]]


@dataclass(frozen=True)
class FaultSpec:
    """``[faults]``: the random fault generator's ranges (uniform draws); times in s,
    bias and stuck forces as fractions of the thruster's range."""

    kinds: tuple[str, ...] = FAULT_KINDS
    each_kind: bool = True  # one case per kind and seed (else the kind is drawn too)
    count: int = 1  # faults per run, on different thrusters
    onset: Range = (10.0, 20.0)
    duration: Range | None = None  # None: until the end of the run
    thrusters: tuple[int, ...] | None = None  # 0-based; None: any
    partial_delta: Range = (0.3, 0.7)
    bias: Range = (0.1, 0.3)
    stuck: Range = (0.2, 0.6)
    intermittent_on: Range = (3.0, 6.0)
    intermittent_off: Range = (5.0, 10.0)


@dataclass(frozen=True)
class HealthySpec:
    """``[healthy]``: fault-free runs of every mode, for the false-alarm statistics."""

    seeds: tuple[int, ...]
    duration_s: float | None
    scenarios: tuple[str, ...] | None  # labels; None: all


@dataclass(frozen=True)
class CampaignSpec:
    name: str
    description: str
    source: str
    seeds: tuple[int, ...]
    variants: tuple[Variant, ...]  # cap and oracle first (references), then the rest
    scenarios: tuple[ScenarioEntry, ...]
    faults: FaultSpec
    healthy: HealthySpec | None
    duration_s: float | None
    metrics: MetricParams
    base: Path | None  # folder relative scenario paths resolve against


def strict(table: Any, allowed: tuple[str, ...] | set[str], where: str) -> dict[str, Any]:
    """``table`` if it is a table with only ``allowed`` keys, else a ConfigError."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table, got {table!r}")
    for key in table:
        if key not in allowed:
            near = difflib.get_close_matches(key, list(allowed), 1)
            hint = f"did you mean {near[0]!r}?" if near else f"known: {sorted(allowed)}"
            raise ConfigError(f"{where}: unknown key {key!r} ({hint})")
    return table


def _number(table: dict[str, Any], key: str, where: str, positive: bool = True) -> float | None:
    if key not in table:
        return None
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"{where}.{key}: expected a finite number, got {v!r}")
    if positive and not v > 0:
        raise ConfigError(f"{where}.{key}: must be > 0, got {v!r}")
    return float(v)


def _range(table: dict[str, Any], key: str, where: str, default: Range | None) -> Range | None:
    if key not in table:
        return default
    v = table[key]
    ok = (
        isinstance(v, list)
        and len(v) == 2
        and all(
            isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in v
        )
    )
    if not ok or not 0 <= v[0] <= v[1]:
        raise ConfigError(f"{where}.{key}: expected [low, high] with 0 <= low <= high, got {v!r}")
    return float(v[0]), float(v[1])


def _ints(v: Any, where: str, low: int = 0) -> tuple[int, ...]:
    if not isinstance(v, list) or not v or not all(type(x) is int and x >= low for x in v):
        raise ConfigError(f"{where}: expected a non-empty list of integers >= {low}, got {v!r}")
    if len(set(v)) != len(v):
        raise ConfigError(f"{where}: duplicates in {v!r}")
    return tuple(v)


def _seeds(table: dict[str, Any], where: str) -> tuple[int, ...]:
    if ("seeds" in table) == ("seed_count" in table):
        raise ConfigError(f"{where}: give seeds = [...] or seed_count = N (one of them)")
    if "seeds" in table:
        return _ints(table["seeds"], f"{where}.seeds")
    n = table["seed_count"]
    if type(n) is not int or n < 1:
        raise ConfigError(f"{where}.seed_count: expected an integer >= 1, got {n!r}")
    return tuple(range(n))


def _scenario(table: Any, where: str) -> ScenarioEntry:
    allowed = ("source", "label", "faults", "set", "duration", "length_m")
    t = strict(table, allowed, where)
    source = t.get("source")
    if not isinstance(source, str) or not source:
        raise ConfigError(f"{where}.source: expected a scenario file or shipped name")
    faults = t.get("faults", "scenario")
    if faults not in FAULT_SOURCES:
        raise ConfigError(f"{where}.faults: expected one of {list(FAULT_SOURCES)}, got {faults!r}")
    label = t.get("label", Path(source).stem)
    if not isinstance(label, str) or not label or "/" in label:
        raise ConfigError(f"{where}.label: expected a name without '/', got {label!r}")
    return ScenarioEntry(
        source,
        label,
        faults,
        strict(t.get("set", {}), set(t.get("set", {})), f"{where}.set"),
        _number(t, "duration", where),
        _number(t, "length_m", where),
    )


def _variant(name: str, table: Any, where: str) -> Variant:
    t = strict(table, ("mode", *VARIANT_TABLES), where)
    mode = PLAIN_MODES.get(t.get("mode", ""))
    if mode is None:
        raise ConfigError(
            f"{where}.mode: expected one of {list(PLAIN_MODES)}, got {t.get('mode')!r}"
        )
    tables = {k: strict(t[k], set(t[k]), f"{where}.{k}") for k in VARIANT_TABLES if k in t}
    return Variant(name, mode, tables)


def _variants(modes: Any, tables: Any, where: str) -> tuple[Variant, ...]:
    if not isinstance(modes, list) or not all(isinstance(m, str) for m in modes):
        raise ConfigError(f"{where}.campaign.modes: expected a list of names, got {modes!r}")
    defined = strict(tables, set(tables), f"{where}.variant")
    for name in defined:
        if name in PLAIN_MODES or name == "none":
            raise ConfigError(f"{where}.variant.{name}: a variant cannot take a mode's name")
    out = [Variant("cap", Mode.CAP, {}), Variant("oracle", Mode.ORACLE, {})]
    for name in dict.fromkeys(modes):
        if name in ("cap", "oracle"):
            continue
        if name in PLAIN_MODES:
            out.append(Variant(name, PLAIN_MODES[name], {}))
        elif name in defined:
            out.append(_variant(name, defined[name], f"{where}.variant.{name}"))
        else:
            known = [*PLAIN_MODES, *defined]
            raise ConfigError(f"{where}.campaign.modes: {name!r} is no mode or [variant] ({known})")
    unused = set(defined) - set(modes)
    if unused:
        raise ConfigError(f"{where}.variant: {sorted(unused)} defined but not in campaign.modes")
    return tuple(out)


def _faults(table: Any, m_where: str) -> FaultSpec:
    where = f"{m_where}.faults"
    t = strict(table, {f.name for f in fields(FaultSpec)}, where)
    d = FaultSpec()
    kinds = t.get("kinds", list(d.kinds))
    if not isinstance(kinds, list) or not kinds or not set(kinds) <= set(FAULT_KINDS):
        raise ConfigError(f"{where}.kinds: expected a list from {list(FAULT_KINDS)}, got {kinds!r}")
    count = t.get("count", 1)
    if type(count) is not int or count < 1:
        raise ConfigError(f"{where}.count: expected an integer >= 1, got {count!r}")
    each = t.get("each_kind", True)
    if not isinstance(each, bool):
        raise ConfigError(f"{where}.each_kind: expected true or false, got {each!r}")
    thr = t.get("thrusters")
    ranges = {
        name: _range(t, name, where, getattr(d, name))
        for name in (
            "onset",
            "duration",
            "partial_delta",
            "bias",
            "stuck",
            "intermittent_on",
            "intermittent_off",
        )
    }
    if ranges["partial_delta"] is not None and ranges["partial_delta"][1] >= 1.0:
        raise ConfigError(f"{where}.partial_delta: must stay below 1, got {t['partial_delta']}")
    return FaultSpec(
        kinds=tuple(dict.fromkeys(kinds)),
        each_kind=each,
        count=count,
        thrusters=None
        if thr is None
        else tuple(i - 1 for i in _ints(thr, f"{where}.thrusters", 1)),
        **ranges,  # type: ignore[arg-type]
    )


def _healthy(table: Any, where: str) -> HealthySpec:
    t = strict(table, ("seeds", "seed_count", "duration", "scenarios"), f"{where}.healthy")
    labels = t.get("scenarios")
    if labels is not None and not (isinstance(labels, list) and labels):
        raise ConfigError(f"{where}.healthy.scenarios: expected a list of labels, got {labels!r}")
    return HealthySpec(
        _seeds(t, f"{where}.healthy"),
        _number(t, "duration", f"{where}.healthy"),
        None if labels is None else tuple(labels),
    )


def _metrics(table: Any, where: str) -> MetricParams:
    t = strict(table, {f.name for f in fields(MetricParams)}, f"{where}.metrics")
    try:
        return MetricParams(**t)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}.metrics: {e}") from e


def parse_campaign(data: dict[str, Any], where: str, base: Path | None = None) -> CampaignSpec:
    top = ("campaign", "scenario", "variant", "faults", "healthy", "metrics")
    strict(data, top, where)
    head = strict(
        data.get("campaign"),
        ("name", "description", "seeds", "seed_count", "modes", "duration"),
        f"{where}.campaign",
    )
    if not isinstance(head.get("name"), str) or not head["name"]:
        raise ConfigError(f"{where}.campaign.name: missing")
    entries = data.get("scenario")
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{where}.scenario: expected at least one [[scenario]]")
    scenarios = tuple(_scenario(e, f"{where}.scenario[{i}]") for i, e in enumerate(entries))
    labels = [s.label for s in scenarios]
    if len(set(labels)) != len(labels):
        raise ConfigError(f"{where}.scenario: duplicate labels in {labels} (set label = ...)")
    healthy = None if "healthy" not in data else _healthy(data["healthy"], where)
    if healthy is not None and not set(healthy.scenarios or ()) <= set(labels):
        raise ConfigError(f"{where}.healthy.scenarios: {healthy.scenarios} not all in {labels}")
    return CampaignSpec(
        name=head["name"],
        description=str(head.get("description", "")),
        source=where,
        seeds=_seeds(head, f"{where}.campaign"),
        variants=_variants(head.get("modes", ["ftcap"]), data.get("variant", {}), where),
        scenarios=scenarios,
        faults=_faults(data.get("faults", {}), where),
        healthy=healthy,
        duration_s=_number(head, "duration", f"{where}.campaign"),
        metrics=_metrics(data.get("metrics", {}), where),
        base=base,
    )


def shipped_campaigns() -> list[str]:
    from ftcap_hil.config.toml import shipped_names

    return shipped_names(SHIPPED)


def load_campaign(name_or_path: str | Path) -> CampaignSpec:
    """A campaign file by path, or the name of a shipped one (``smoke``)."""
    doc = read_toml(name_or_path, SHIPPED, what="campaign")
    return parse_campaign(doc.data, doc.source, doc.base)
