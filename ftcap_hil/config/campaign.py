"""Campaign files (TOML): scenarios x seeds x modes, fault generation, healthy runs, metrics.

The format is documented in ``docs/campaigns.md``; shipped files live in
``ftcap_hil/data/campaigns``. Read with :class:`~ftcap_hil.config.tables.Table`: an unknown
key is an error that names the file, the table, the key and the nearest valid key. What a
scenario override or a variant sets is checked by the scenario reader when the plan is
built.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ftcap_hil.config.table_dataclass import read_dataclass
from ftcap_hil.config.tables import Table
from ftcap_hil.config.toml import read_toml
from ftcap_hil.core.status import Mode

SHIPPED = "ftcap_hil.data.campaigns"
PLAIN_MODES = {m.value: m for m in Mode if m is not Mode.NONE}
VARIANT_TABLES = ("estimator", "excitation", "allocator", "diagnosis")
Range = tuple[float, float]


class FaultSource(enum.Enum):
    """Where a ``[[scenario]]`` entry's faults come from (``faults = ...``)."""

    SCENARIO = "scenario"  # the file's own [[fault]] schedule
    RANDOM = "random"  # drawn from [faults]
    NONE = "none"  # none: healthy runs


class DrawnKind(enum.Enum):
    """The kinds of fault the campaign's generator draws (``[faults] kinds``); the values
    are the kind labels of the results."""

    DEAD = "dead"
    STUCK = "stuck"
    PARTIAL = "partial"
    BIAS = "bias"
    INTERMITTENT = "intermittent"
    RAMP = "ramp"  # a gradual loss: delta falls linearly to its final value
    FROZEN = "frozen"  # the output frozen at its onset value
    TRANSIENT = "transient"  # dead for a while, then working again (recovery)
    DOUBLE = "double"  # two thrusters dead at once
    TELEMETRY_LOST = "telemetry-lost"  # a working thruster whose drive stops reporting


#: The kinds a ``[faults]`` table without ``kinds`` draws (the first generator's).
CLASSIC_KINDS = (DrawnKind.DEAD, DrawnKind.STUCK, DrawnKind.PARTIAL, DrawnKind.BIAS,
                 DrawnKind.INTERMITTENT)  # fmt: skip


class HarmStatistic(enum.Enum):
    """Which statistic of a phase's tracking error (or deviation) judges harm."""

    MAX = "max"
    RMS = "rms"


class HarmBasis(enum.Enum):
    """What harm is judged on: the distance to the reference the operator asked for
    (``tracking``), or to the fault-free run of the same case (``deviation``: with a model
    error, an estimator that corrects it strays from the fault-free run while tracking
    better, and counted as harm)."""

    TRACKING = "tracking"
    DEVIATION = "deviation"


@dataclass(frozen=True)
class MetricParams:
    """The metrics' parameters (``[metrics]`` of a campaign file); times in s."""

    convergence_tol: float = 0.1  # |delta_hat - delta| counted as "estimated"
    converge_hold_s: float = 2.0  # ... held this long
    used_fraction: float = 0.1  # |u| >= this x range: the thruster is "used"
    used_window_s: float = 5.0  # "used" judged over this long after the onset
    tail_fraction: float = 0.25  # last part of an episode for errors and isolation
    isolation_hold: float = 0.9  # share of the tail isolated for "correct isolation"
    recovery_hold_s: float = 2.0  # back in the allocation, at its true effectiveness, this long
    episode_merge_s: float = 2.0  # a false flag rising this soon after the last one fell: one
    harm_ratio: float = 1.05  # harm: deviation > harm_ratio x max(CAP's, the oracle's)
    harm_statistic: HarmStatistic = HarmStatistic.MAX  # per phase, of the tracking error
    harm_basis: HarmBasis = HarmBasis.TRACKING

    def __post_init__(self) -> None:
        for name in (
            "convergence_tol", "converge_hold_s", "used_window_s", "recovery_hold_s",
            "episode_merge_s",
        ):  # fmt: skip
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: must be > 0, got {getattr(self, name)}")
        for name in ("used_fraction", "tail_fraction", "isolation_hold"):
            if not 0 < getattr(self, name) <= 1:
                raise ValueError(f"{name}: need (0, 1], got {getattr(self, name)}")
        if not self.harm_ratio >= 1:
            raise ValueError(f"harm_ratio: must be >= 1, got {self.harm_ratio}")
        if not isinstance(self.harm_statistic, HarmStatistic):
            raise ValueError(f"harm_statistic: a HarmStatistic, got {self.harm_statistic!r}")
        if not isinstance(self.harm_basis, HarmBasis):
            raise ValueError(f"harm_basis: a HarmBasis, got {self.harm_basis!r}")


@dataclass(frozen=True)
class ScenarioEntry:
    """One ``[[scenario]]``: a scenario file (path or shipped name) and what changes in it."""

    source: str
    label: str
    faults: FaultSource
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

    kinds: tuple[DrawnKind, ...] = CLASSIC_KINDS
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
    ramp_delta: Range = (0.0, 0.5)  # a ramp's final delta
    ramp_s: Range = (30.0, 120.0)  # how long it takes to get there
    transient_s: Range = (20.0, 60.0)  # how long a transient fault lasts
    causes: bool = False  # draw each fault's physical cause (vessels with drives)


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
    tuning_seeds: tuple[int, ...] = ()  # where the thresholds were calibrated: not evaluated


def _range(t: Table, key: str, default: Range | None) -> Range | None:
    """``[low, high]`` with 0 <= low <= high (``default`` if absent)."""
    if not t.has(key):
        t.allow(key)
        return default
    low, high = t.vector(key, 2, lo=0.0)
    if low > high:
        raise t.error(key, f"expected [low, high] with low <= high, got {t.value(key)!r}")
    return float(low), float(high)


def _distinct(t: Table, key: str, low: int) -> tuple[int, ...]:
    values = t.integers(key, None, lo=low)
    if not values or len(set(values)) != len(values):
        raise t.error(key, f"expected distinct integers >= {low}, got {list(values)}")
    return values


def _seeds(t: Table) -> tuple[int, ...]:
    if t.has("seeds") == t.has("seed_count"):
        raise t.error(None, "give seeds = [...] or seed_count = N (one of them)")
    t.allow("seeds", "seed_count")
    if t.has("seeds"):
        return _distinct(t, "seeds", 0)
    return tuple(range(t.integer("seed_count", lo=1)))


def _free_table(t: Table, key: str) -> dict[str, Any]:
    """A table copied as it is (checked later, by the scenario reader, when planned)."""
    value = t.value(key, {})
    if not isinstance(value, dict):
        raise t.error(key, f"expected a table, got {value!r}")
    return value


def _scenario(t: Table) -> ScenarioEntry:
    source = t.string("source")
    label = t.string("label", Path(source).stem)
    if "/" in label:
        raise t.error("label", f"expected a name without '/', got {label!r}")
    return ScenarioEntry(
        source,
        label,
        t.enum("faults", FaultSource, FaultSource.SCENARIO),
        _free_table(t, "set"),
        t.number("duration", None, positive=True),
        t.number("length_m", None, positive=True),
    )


def _variant(name: str, t: Table) -> Variant:
    mode = PLAIN_MODES[t.choice("mode", list(PLAIN_MODES))]
    tables = {k: _free_table(t, k) for k in VARIANT_TABLES if t.has(k)}
    t.allow(*VARIANT_TABLES)
    return Variant(name, mode, tables)


def _variants(head: Table, root: Table) -> tuple[Variant, ...]:
    modes = head.strings("modes", ["ftcap"])
    defined = root.table("variant")
    for name in defined.data:
        if name in PLAIN_MODES or name == "none":
            raise defined.error(name, "a variant cannot take a mode's name")
    out = [Variant("cap", Mode.CAP, {}), Variant("oracle", Mode.ORACLE, {})]
    for name in dict.fromkeys(modes):
        if name in ("cap", "oracle"):
            continue
        if name in PLAIN_MODES:
            out.append(Variant(name, PLAIN_MODES[name], {}))
        elif name in defined.data:
            out.append(_variant(name, defined.table(name)))
        else:
            known = [*PLAIN_MODES, *defined.data]
            raise head.error("modes", f"{name!r} is no mode or [variant] ({known})")
    if unused := sorted(set(defined.data) - set(modes)):
        raise defined.error(None, f"{unused} defined but not in [campaign] modes")
    return tuple(out)


RANGES: tuple[str, ...] = ("onset", "duration", "partial_delta", "bias", "stuck")
RANGES += ("intermittent_on", "intermittent_off", "ramp_delta", "ramp_s", "transient_s")


def _faults(t: Table) -> FaultSpec:
    d = FaultSpec()
    names = [k.value for k in DrawnKind]
    kinds = t.strings("kinds", [k.value for k in d.kinds])
    if not kinds or not set(kinds) <= set(names):
        raise t.error("kinds", f"expected a list from {names}, got {list(kinds)}")
    ranges = {name: _range(t, name, getattr(d, name)) for name in RANGES}
    if ranges["partial_delta"] is not None and ranges["partial_delta"][1] >= 1.0:
        raise t.error("partial_delta", f"must stay below 1, got {list(ranges['partial_delta'])}")
    thrusters = _distinct(t, "thrusters", 1) if t.has("thrusters") else None
    t.allow("thrusters")
    return FaultSpec(
        kinds=tuple(DrawnKind(k) for k in dict.fromkeys(kinds)),
        each_kind=t.boolean("each_kind", d.each_kind),
        count=t.integer("count", d.count, lo=1),
        causes=t.boolean("causes", d.causes),
        thrusters=None if thrusters is None else tuple(i - 1 for i in thrusters),
        **ranges,  # type: ignore[arg-type]
    )


def _healthy(t: Table, labels: list[str]) -> HealthySpec:
    chosen = t.strings("scenarios") if t.has("scenarios") else None
    t.allow("scenarios")
    if chosen is not None and (not chosen or not set(chosen) <= set(labels)):
        raise t.error("scenarios", f"expected labels from {labels}, got {list(chosen)}")
    return HealthySpec(_seeds(t), t.number("duration", None, positive=True), chosen)


def campaign_from(root: Table, base: Path | None = None) -> CampaignSpec:
    """A campaign from the top level of its file (module docstring)."""
    head = root.table("campaign", required=True)
    scenarios = tuple(_scenario(e) for e in root.tables("scenario", required=True))
    labels = [s.label for s in scenarios]
    if len(set(labels)) != len(labels):
        raise root.error("scenario", f"duplicate labels in {labels} (set label = ...)")
    healthy = _healthy(root.table("healthy"), labels) if root.has("healthy") else None
    root.allow("healthy")
    seeds = _seeds(head)
    return CampaignSpec(
        name=head.string("name"),
        description=head.string("description", ""),
        source=root.file,
        seeds=seeds,
        variants=_variants(head, root),
        scenarios=scenarios,
        faults=_faults(root.table("faults")),
        healthy=healthy,
        duration_s=head.number("duration", None, positive=True),
        metrics=read_dataclass(root.table("metrics"), MetricParams),
        base=base,
        tuning_seeds=_tuning_seeds(head, seeds + (healthy.seeds if healthy else ())),
    )


def _tuning_seeds(head: Table, evaluated: tuple[int, ...]) -> tuple[int, ...]:
    """``[campaign] tuning_seeds``: the seeds the thresholds were calibrated on (for
    example bench/calibrate_shaft.py's); none of them may be an evaluation seed."""
    if not head.has("tuning_seeds"):
        head.allow("tuning_seeds")
        return ()
    tuning = _distinct(head, "tuning_seeds", 0)
    overlap = sorted(set(tuning) & set(evaluated))
    if overlap:
        raise head.error(
            "tuning_seeds",
            f"seeds {overlap} are also evaluated here: judge thresholds on other seeds "
            "than the ones they were tuned on",
        )
    return tuning


def parse_campaign(data: dict[str, Any], where: str, base: Path | None = None) -> CampaignSpec:
    """A campaign from a parsed TOML document (``where`` names the file in messages)."""
    with Table(data, where) as root:
        return campaign_from(root, base)


def shipped_campaigns() -> list[str]:
    from ftcap_hil.config.toml import shipped_names

    return shipped_names(SHIPPED)


def load_campaign(name_or_path: str | Path) -> CampaignSpec:
    """A campaign file by path, or the name of a shipped one (``smoke``)."""
    doc = read_toml(name_or_path, SHIPPED, what="campaign")
    return parse_campaign(doc.data, doc.source, doc.base)
