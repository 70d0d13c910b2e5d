"""Thruster curves named in a ``[can]`` table: ``thruster_curve`` and ``curve_thrust_max_n``.

``thruster_curve`` is one curve for every thruster or a list of m (vessel-file order), each
a TOML file or the name of a shipped one (``ftcap_hil/data/thrusters``: ``t200-12v``, ...)
with keys ``name``, ``source``, ``fraction``, ``thrust_n``
(:mod:`ftcap_hil.core.effectiveness.thruster_curve`). ``curve_thrust_max_n`` (optional, one
value or m)
scales each curve so that full ahead gives that thrust in N: a published curve's shape on a
model whose thrusters are smaller. Without ``thruster_curve`` the force map is linear.
"""

from __future__ import annotations

import math
from dataclasses import replace

from ftcap_hil.config.tables import Table
from ftcap_hil.config.toml import read_toml, shipped_names
from ftcap_hil.core.effectiveness.geometry import ThrusterSet
from ftcap_hil.core.effectiveness.thruster_curve import ThrusterCurve
from ftcap_hil.core.errors import ConfigError

THRUSTER_DATA = "ftcap_hil.data.thrusters"


def shipped_curves() -> list[str]:
    """Names of the shipped curve files."""
    return shipped_names(THRUSTER_DATA)


def load_curve(name_or_path: str) -> ThrusterCurve:
    """One curve file (path, or shipped name); ConfigError names the file and the key."""
    doc = read_toml(name_or_path, THRUSTER_DATA, what="thruster curve")
    with Table.document(doc) as t:
        t.allow("source")  # documentation: where the data came from
        name = t.string("name", doc.source)
        return ThrusterCurve.from_table(
            t.vector("fraction"), t.vector("thrust_n"), f"{doc.source} ({name})"
        )


def _per_thruster(t: Table, key: str, m: int) -> list[object]:
    raw = t.value(key)
    values = list(raw) if isinstance(raw, list) else [raw] * m
    if len(values) != m:
        raise t.error(key, f"expected one value or {m} (one per thruster), got {len(values)}")
    return values


def curves_from(t: Table, m: int) -> tuple[ThrusterCurve, ...] | None:
    """``thruster_curve`` (+ ``curve_thrust_max_n``) of a [can] table for m thrusters, or
    None (the linear map) without ``thruster_curve``."""
    if not t.has("thruster_curve"):
        if t.has("curve_thrust_max_n"):
            raise t.error("curve_thrust_max_n", "needs thruster_curve")
        return None
    names = _per_thruster(t, "thruster_curve", m)
    if not all(isinstance(n, str) and n for n in names):
        raise t.error("thruster_curve", f"expected curve names or files, got {names!r}")
    scales: list[float | None] = [None] * m
    if t.has("curve_thrust_max_n"):
        scales = [_positive(t, v) for v in _per_thruster(t, "curve_thrust_max_n", m)]
    cache: dict[str, ThrusterCurve] = {}
    out = []
    for name, scale in zip(names, scales, strict=True):
        try:
            curve = cache[str(name)] if str(name) in cache else load_curve(str(name))
        except ConfigError as e:
            raise t.error("thruster_curve", str(e)) from e
        cache[str(name)] = curve
        out.append(curve if scale is None else curve.scaled(scale))
    return tuple(out)


def _positive(t: Table, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise t.error("curve_thrust_max_n", f"expected a thrust > 0 N, got {value!r}")
    if not (math.isfinite(value) and value > 0):
        raise t.error("curve_thrust_max_n", f"expected a thrust > 0 N, got {value!r}")
    return float(value)


def limited_to_curves(ths: ThrusterSet, curves: tuple[ThrusterCurve, ...] | None) -> ThrusterSet:
    """The thrusters with each amplitude limit cut to what its curve can give (a reverse
    weaker than forward, a unidirectional thruster's u_min = 0): the allocator then never
    asks for thrust the ESC cannot make. Unchanged without curves."""
    if curves is None:
        return ths
    return ThrusterSet(
        tuple(
            replace(th, u_min=max(th.u_min, c.thrust_min_n), u_max=min(th.u_max, c.thrust_max_n))
            for th, c in zip(ths.thrusters, curves, strict=True)
        ),
        ths.dofs,
    )
