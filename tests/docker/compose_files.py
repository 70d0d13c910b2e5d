"""Reading docker/compose.yaml and docker/Dockerfile the way Docker does, for the tests (no
tests here: test_compose_files.py checks this reader).

Compose: YAML with ``<<`` merge keys, later ``-f`` files merged onto earlier ones (``!reset``,
``!override``), ``${VAR:-default}`` interpolation, string commands split into shell words,
``depends_on`` (with the implicit dependency of ``network_mode: service:X``) and profiles.
Dockerfile: the runtime stage's ENTRYPOINT, CMD, ENV, USER and the files it COPYs from the
build context. Only what our files use is implemented; anything else fails loudly.
Plus :func:`unknown_set_keys`, the check of ``--set`` keys against the shipped configs.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

yaml = pytest.importorskip("yaml")

ROOT = Path(__file__).resolve().parents[2]
DOCKER = ROOT / "docker"
COMPOSE = DOCKER / "compose.yaml"
COMPOSE_VCAN = DOCKER / "compose.vcan.yaml"
DOCKERFILE = DOCKER / "Dockerfile"
EXIT_SERVICE = "gcs"  # `docker compose up --exit-code-from gcs`

# ---------------------------------------------------------------- compose files


class _Reset:
    """``!reset``: remove the key from what the earlier files said."""


RESET = _Reset()


@dataclass(frozen=True)
class _Override:
    """``!override``: replace instead of merging."""

    value: Any


class _ComposeLoader(yaml.SafeLoader):
    pass


def _construct_any(loader: yaml.SafeLoader, node: yaml.Node) -> Any:
    if isinstance(node, yaml.MappingNode):
        return loader.construct_mapping(node, deep=True)
    if isinstance(node, yaml.SequenceNode):
        return loader.construct_sequence(node, deep=True)
    return loader.construct_scalar(node)


_ComposeLoader.add_constructor("!reset", lambda loader, node: RESET)
_ComposeLoader.add_constructor(
    "!override", lambda loader, node: _Override(_construct_any(loader, node))
)

# Sequences that compose merges across files (the others are replaced).
_APPENDED = {"ports", "expose", "volumes", "extra_hosts", "dns", "cap_add", "cap_drop"}


def _plain(value: Any) -> Any:
    if isinstance(value, _Override):
        return _plain(value.value)
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items() if v is not RESET}
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value


def merge(base: Any, over: Any, key: str = "") -> Any:
    """Compose's merge of ``over`` (a later -f file) onto ``base``, for what our files use."""
    if isinstance(over, _Override):
        return _plain(over.value)
    if isinstance(base, dict) and isinstance(over, dict):
        out = dict(base)
        for k, v in over.items():
            if v is RESET:
                out.pop(k, None)
            else:
                out[k] = merge(out[k], v, k) if k in out else _plain(v)
        return out
    if isinstance(base, list) and isinstance(over, list) and key in _APPENDED:
        return base + [v for v in _plain(over) if v not in base]
    return _plain(over)


def load_compose_raw(*files: Path) -> dict[str, Any]:
    """The files merged in order, before interpolation (``<<`` merge keys resolved)."""
    out: dict[str, Any] = {}
    for f in files:
        data = yaml.load(f.read_text(), Loader=_ComposeLoader)  # noqa: S506 - SafeLoader subclass
        out = merge(out, data)
    return _plain(out)


_VAR = re.compile(r"\$(?:(?P<dollar>\$)|\{(?P<braced>[^{}]*)\}|(?P<named>[A-Za-z_][A-Za-z0-9_]*))")
_BRACED = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?:(:?[-?+])(.*))?", re.S)


def _substitute(m: re.Match[str], env: Mapping[str, str]) -> str:
    if m["dollar"]:
        return "$"
    if m["named"]:
        return env.get(m["named"], "")
    parts = _BRACED.fullmatch(m["braced"])
    if parts is None:
        raise ValueError(f"invalid interpolation ${{{m['braced']}}}")
    name, op, arg = parts.groups()
    value = env.get(name)
    if op is None:
        return value or ""
    missing = value is None or (op.startswith(":") and value == "")
    if op.endswith("-"):
        return interpolate(arg, env) if missing else str(value)
    if op.endswith("?"):
        if missing:
            raise ValueError(f"{name}: {arg or 'required variable is missing'}")
        return str(value)
    return "" if missing else interpolate(arg, env)  # "+"


def interpolate(value: Any, env: Mapping[str, str]) -> Any:
    """Compose's interpolation: ``$VAR``, ``${VAR}``, ``:-``, ``-``, ``:?``, ``:+``, ``$$``."""
    if isinstance(value, str):
        return _VAR.sub(lambda m: _substitute(m, env), value)
    if isinstance(value, dict):
        return {k: interpolate(v, env) for k, v in value.items()}
    if isinstance(value, list):
        return [interpolate(v, env) for v in value]
    return value


def load_compose(*files: Path, env: Mapping[str, str] | None = None) -> dict[str, Any]:
    return interpolate(load_compose_raw(*files), os.environ if env is None else env)


def argv_of(value: Any) -> list[str]:
    """``command``/``entrypoint``: a list as is, a string split like compose does (shell words)."""
    if value is None:
        return []
    if isinstance(value, str):
        return shlex.split(value)
    return [str(v) for v in value]


def parse_duration(text: str | int | float) -> float:
    """Compose durations: ``1m30s``, ``500ms``, ``10s``, or plain seconds."""
    if isinstance(text, int | float):
        return float(text)
    units = {"h": 3600.0, "m": 60.0, "s": 1.0, "ms": 1e-3, "us": 1e-6}
    parts = re.findall(r"(\d+(?:\.\d+)?)(ms|us|h|m|s)", text)
    if not parts or "".join(n + u for n, u in parts) != text:
        raise ValueError(f"duration {text!r}")
    return sum(float(n) * units[u] for n, u in parts)


def depends_on(spec: Mapping[str, Any]) -> dict[str, str]:
    """{service: condition}, including the implicit one of ``network_mode: service:X``."""
    deps = spec.get("depends_on", {})
    out = (
        {name: "service_started" for name in deps}
        if isinstance(deps, list)
        else {name: (v or {}).get("condition", "service_started") for name, v in deps.items()}
    )
    mode = str(spec.get("network_mode", ""))
    if mode.startswith("service:"):
        out.setdefault(mode.removeprefix("service:"), "service_started")
    return out


def start_order(services: Mapping[str, Any]) -> list[str]:
    order: list[str] = []

    def visit(name: str, path: tuple[str, ...]) -> None:
        if name in order:
            return
        if name in path:
            raise ValueError(f"depends_on cycle: {' -> '.join((*path, name))}")
        if name not in services:
            raise ValueError(f"{path[-1]} depends on undefined service {name!r}")
        for dep in depends_on(services[name]):
            visit(dep, (*path, name))
        order.append(name)

    for name in services:
        if not services[name].get("profiles"):  # compose starts no profiled service by default
            visit(name, ())
    return order


# ---------------------------------------------------------------- the image, from its Dockerfile


@dataclass(frozen=True)
class Image:
    """What the runtime stage of docker/Dockerfile gives a container."""

    base: str
    entrypoint: list[str]
    cmd: list[str]
    env: dict[str, str]
    user: str
    copies: dict[str, Path]  # container path -> file in the build context (the repo)


def dockerfile_instructions(path: Path = DOCKERFILE) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with continuation lines joined and comments dropped."""
    out: list[tuple[str, str]] = []
    pending = ""
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not pending and (not line or line.startswith("#")):
            continue
        if line.startswith("#"):
            continue
        pending = f"{pending} {line}" if pending else line
        if pending.endswith("\\"):
            pending = pending[:-1].rstrip()
            continue
        word, _, rest = pending.partition(" ")
        out.append((word.upper(), rest.strip()))
        pending = ""
    return out


def read_image(path: Path = DOCKERFILE) -> Image:
    args: dict[str, str] = {}
    stage: dict[str, Any] = {}

    def expand(text: str) -> str:
        return re.sub(r"\$\{(\w+)\}", lambda m: args.get(m[1], ""), text)

    for word, rest in dockerfile_instructions(path):
        if word == "ARG":
            name, _, default = rest.partition("=")
            args[name] = default
        elif word == "FROM":
            stage = {"base": expand(rest.split()[0]), "env": {}, "copies": {}, "user": "root"}
            stage |= {"entrypoint": [], "cmd": []}
        elif word == "ENV":
            for item in shlex.split(rest):
                key, _, value = item.partition("=")
                stage["env"][key] = value
        elif word in ("ENTRYPOINT", "CMD"):
            stage[word.lower()] = json.loads(rest)
        elif word == "USER":
            stage["user"] = expand(rest)
        elif word == "COPY" and "--from" not in rest:
            *sources, target = [t for t in shlex.split(rest) if not t.startswith("--")]
            for src in sources:
                local = ROOT / src
                dst = f"{target.rstrip('/')}/{local.name}" if target.endswith("/") else target
                stage["copies"][dst] = local
    return Image(**stage)


# ---------------------------------------------------------------- product configuration keys


def unknown_set_keys(argv: list[str]) -> list[str]:
    """``--set SECTION.KEY=VALUE`` whose key the shipped config of that subcommand lacks.

    The product refuses such a key when it starts (every table is strict); checking it here
    finds a misspelt key in the compose files without starting a container.
    """
    from ftcap_hil.config.mission import GCS_KEYS, MISSION_KEYS
    from ftcap_hil.config.toml import shipped_config

    sub = argv[1] if len(argv) > 1 else ""
    known: dict[str, set[str]]
    if sub in ("allocator", "sim"):
        name = "allocator.toml" if sub == "allocator" else "vessel.toml"
        data = tomllib.loads(shipped_config(name).read_text())
        known = {s: set(t) for s, t in data.items() if isinstance(t, dict)}
    elif sub == "gcs":
        known = {"mission": set(MISSION_KEYS), "gcs": set(GCS_KEYS)}
    else:
        known = {}
    bad = []
    for flag, value in zip(argv, argv[1:], strict=False):
        if flag == "--set":
            section, _, key = value.split("=", 1)[0].partition(".")
            if key not in known.get(section, set()):
                bad.append(f"{sub}: --set {value}")
    return bad


def is_ours(spec: Mapping[str, Any]) -> bool:
    """Built from docker/Dockerfile (the others are third-party images)."""
    build = spec.get("build") or {}
    return isinstance(build, dict) and build.get("dockerfile") == "docker/Dockerfile"


def container_argv(spec: Mapping[str, Any], image: Image) -> list[str]:
    """What the container runs: ENTRYPOINT + CMD, each overridden by the service."""
    entry = argv_of(spec["entrypoint"]) if "entrypoint" in spec else list(image.entrypoint)
    cmd = argv_of(spec["command"]) if "command" in spec else list(image.cmd)
    return entry + cmd


def gcs_mission(compose: Mapping[str, Any], image: Image) -> tuple[str, list[str]]:
    """(mission name, container argv) of the ground-station service."""
    argv = container_argv(compose["services"][EXIT_SERVICE], image)
    return argv[argv.index("--mission") + 1], argv
