"""Reading the project's TOML files: one reader, ``--set`` overrides, errors that name the file.

Precedence everywhere (python-can's): command-line ``--set SECTION.KEY=VALUE`` > file >
defaults. A file is a path or the name of a file shipped in ``ftcap_hil/data``.
"""

from __future__ import annotations

import copy
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from ftcap_hil.core.errors import ConfigError

HIL_DATA = "ftcap_hil.data.hil"


@dataclass(frozen=True)
class TomlFile:
    """A parsed TOML document, where it came from (for messages), and the folder that
    relative references inside it resolve against (None for a shipped file)."""

    data: dict[str, Any]
    source: str
    base: Path | None = None


def parse_toml(text: str | bytes, source: str) -> dict[str, Any]:
    """TOML text -> dict; a syntax error is a ConfigError naming ``source``."""
    try:
        return tomllib.loads(text.decode() if isinstance(text, bytes) else text)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ConfigError(f"{source}: {e}") from e


def shipped_names(package: str) -> list[str]:
    """Names (without ``.toml``) of the TOML files shipped in ``package``."""
    return sorted(
        p.name[:-5] for p in resources.files(package).iterdir() if p.name.endswith(".toml")
    )


def read_toml(
    name_or_path: str | Path,
    package: str | None = None,
    overrides: list[str] | None = None,
    what: str = "file",
) -> TomlFile:
    """A TOML file by path, or by shipped name in ``package``, with overrides applied."""
    path = Path(name_or_path)
    if path.is_file():
        doc = TomlFile(parse_toml(path.read_bytes(), str(path)), str(path), path.parent)
    elif package is not None and (name := str(name_or_path).removesuffix(".toml")) in (
        shipped_names(package)
    ):
        text = resources.files(package).joinpath(f"{name}.toml").read_bytes()
        doc = TomlFile(parse_toml(text, f"{name}.toml"), f"{name}.toml")
    else:
        known = f" or shipped {what} {shipped_names(package)}" if package is not None else ""
        raise ConfigError(f"{what} {str(name_or_path)!r}: no such file{known}")
    if overrides:
        doc = TomlFile(apply_overrides(doc.data, overrides), doc.source, doc.base)
    return doc


def shipped_config(name: str) -> Path:
    path = Path(str(resources.files(HIL_DATA).joinpath(name)))
    if not path.exists():
        raise ConfigError(f"no shipped config {name!r} in {HIL_DATA}")
    return path


def apply_overrides(data: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """``section.key=value`` with value parsed as TOML (strings may be bare)."""
    out = copy.deepcopy(data)
    for item in overrides:
        if "=" not in item or "." not in item.split("=", 1)[0]:
            raise ConfigError(f"--set {item!r}: expected SECTION.KEY=VALUE")
        key, text = item.split("=", 1)
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text
        *path, leaf = key.split(".")
        table = out
        for part in path:
            table = table.setdefault(part, {})
            if not isinstance(table, dict):
                raise ConfigError(f"--set {item!r}: {part!r} is not a table")
        table[leaf] = value
    return out
