"""Zenoh session settings for ftcap: role defaults, ``--cfg KEY:VALUE``, the safety check.

Pure (no zenoh import): settings are ``{config key: JSON5 text}`` to be inserted with
``zenoh.Config.insert_json5``, and the check reads a ``{config key: decoded JSON value}``
mapping (what ``zenoh.Config.get_json`` returns). ``bridges.zenoh_io.link`` does the zenoh part.

Network policy enforced by :func:`check_settings` (the start-up check of every session):

* ``scouting/multicast/enabled`` must be explicitly ``false`` (zenoh's default is on);
* no endpoint in the effective ``listen/endpoints`` may bind all interfaces
  (``0.0.0.0``, ``[::]`` or an empty host): listen on ``127.0.0.1`` or a named interface address;
* a router must listen somewhere, and a client must have a ``connect/endpoints`` entry,
  since with scouting off nothing else would find the peer;
* an endpoint beyond loopback needs ``tls/`` or ``quic/`` with mutual TLS, and a router
  access control denying by default, unless the caller allows it unauthenticated
  (``[zenoh] allow_unauthenticated``).

Unknown keys: zenoh itself refuses them, in a file (``Config.from_file``, serde's
``unknown field `x`, expected one of ...`` at every level except the free-form ``plugins``
tables) and in an override (``insert_json5``: ``unknown key``). :func:`describe_file_error`
and :func:`describe_override_error` restate those errors in the project's form: the file,
the table (found in zenoh's default configuration by its set of valid keys), the key, the
nearest valid key and the valid keys.

Shipped files, ``ftcap_hil/data/zenoh/{allocator,vessel,gcs}.json5``, put the allocator in
``router`` mode on ``tcp/127.0.0.1:7447`` and the vessel and ground station in ``client`` mode
connecting to it.
"""

from __future__ import annotations

import difflib
import enum
import ipaddress
import json
import re
from collections.abc import Iterator, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from ftcap_hil.core.errors import ConfigError

DEFAULT_PORT = 7447
LOOPBACK = "127.0.0.1"
SHIPPED_CONFIGS = ("allocator", "vessel", "gcs", "allocator-tls", "vessel-tls", "gcs-tls")
CHECKED_KEYS = (
    "mode",
    "listen/endpoints",
    "connect/endpoints",
    "scouting/multicast/enabled",
    "transport/link/tls/enable_mtls",
    "access_control/enabled",
    "access_control/default_permission",
)
AUTHENTICATED_PROTOCOLS = ("tls", "quic")  # with mutual TLS: both ends show a certificate


class ZenohConfigError(ConfigError):
    """A Zenoh configuration that must not be used; the message names the key and value."""


class ZenohRole(enum.Enum):
    """A Zenoh session's mode (``mode`` in the JSON5 config)."""

    ROUTER = "router"  # the allocator daemon: listens
    PEER = "peer"
    CLIENT = "client"  # vessel, ground station: connect to the router


def endpoint(host: str, port: int, protocol: str = "tcp") -> str:
    """``tcp/127.0.0.1:7447``; an IPv6 literal is bracketed."""
    if not 0 <= port <= 65535:
        raise ZenohConfigError(f"port {port}: expected 0..65535")
    if ":" in host and not host.startswith("["):
        host = f"[{host}]"
    return f"{protocol}/{host}:{port}"


def role_settings(
    role: ZenohRole | str, port: int = DEFAULT_PORT, host: str = LOOPBACK
) -> dict[str, str]:
    """Settings (key -> JSON5 text) for a session of ``role`` on ``host:port``.

    A router listens on ``tcp/host:port``; a client or peer connects there and listens nowhere.
    Gossip is off too: every session talks to the one router, so there is nothing to gossip.
    Shared memory is off: the payloads are small JSON, and each session that joins a router
    over shared memory maps a segment there that stays resident after it leaves (about
    20 MB per client session on loopback).
    """
    role = _role(role, "role")
    here = json.dumps([endpoint(host, port)])
    settings = {
        "mode": json.dumps(role.value),
        "scouting/multicast/enabled": "false",
        "scouting/gossip/enabled": "false",
        "transport/shared_memory/enabled": "false",
    }
    if role is ZenohRole.ROUTER:
        settings |= {"listen/endpoints": here, "connect/endpoints": "[]"}
    else:
        settings |= {"connect/endpoints": here, "listen/endpoints": "[]"}
    return settings


def parse_override(text: str) -> tuple[str, str]:
    """Split one ``--cfg`` argument ``KEY:VALUE`` (VALUE is JSON5) at the first colon."""
    key, sep, value = text.partition(":")
    key = key.strip().strip("/")
    if not sep or not key or not value.strip():
        raise ZenohConfigError(
            f"--cfg {text!r}: expected KEY:VALUE with a JSON5 value, "
            "e.g. 'connect/endpoints:[\"tcp/127.0.0.1:7447\"]'"
        )
    return key, value.strip()


def endpoint_host(locator: str) -> str | None:
    """Host part of ``proto/host:port[?meta][#config]``; None for hostless (unix socket) ones."""
    _, sep, address = locator.partition("/")
    if not sep:
        raise ZenohConfigError(f"endpoint {locator!r}: expected PROTOCOL/ADDRESS")
    address = address.split("?", 1)[0].split("#", 1)[0]
    if address.startswith("["):
        return address[1 : address.find("]")] if "]" in address else None
    if ":" not in address:
        return None
    return address.rsplit(":", 1)[0]


def binds_all_interfaces(locator: str) -> bool:
    """The locator listens on every interface: an empty host, 0.0.0.0, [::] and the like."""
    host = endpoint_host(locator)
    if host is None:
        return False
    if host == "":
        return True
    try:
        return ipaddress.ip_address(host.split("%", 1)[0]).is_unspecified
    except ValueError:  # a host name: resolved by zenoh, never the wildcard address
        return False


def is_loopback(locator: str) -> bool:
    """The locator stays on this machine: a loopback address, ``localhost`` or no host at
    all (a unix socket)."""
    host = endpoint_host(locator)
    if host is None:
        return True
    name = host.split("%", 1)[0]
    if name == "localhost":
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:  # another host name: not known to stay here
        return False


def unauthenticated_exposure(values: Mapping[str, Any], role: ZenohRole) -> str | None:
    """The first endpoint beyond loopback that does not authenticate who is at its other
    end (``KEY contains LOCATOR``), None if there is none. Authenticated: a ``tls/`` or
    ``quic/`` locator with mutual TLS (``transport/link/tls/enable_mtls``), and on a router
    access control denying by default (any certified client could put on any key else)."""
    mtls = values.get("transport/link/tls/enable_mtls") is True
    acl = values.get("access_control/enabled") is True and (
        values.get("access_control/default_permission") == "deny"
    )
    for name in ("listen/endpoints", "connect/endpoints"):
        key, locators = _for_mode(values.get(name), name, role)
        for locator in locators:
            if is_loopback(locator):
                continue
            secured = locator.split("/", 1)[0] in AUTHENTICATED_PROTOCOLS and mtls
            if not (secured and (acl or role is not ZenohRole.ROUTER)):
                return f"{key} contains {locator!r}"
    return None


def check_settings(
    values: Mapping[str, Any], source: str = "zenoh config", allow_unauthenticated: bool = False,
) -> ZenohRole:  # fmt: skip
    """Refuse a configuration that breaks the network policy; return the session role.

    ``values`` maps each key of :data:`CHECKED_KEYS` to its decoded JSON value (None = unset).
    An endpoint beyond loopback without mutual TLS and access control is refused unless
    ``allow_unauthenticated`` (:func:`unauthenticated_exposure`).
    """
    role = _role(values.get("mode") or ZenohRole.PEER.value, f"{source}: mode")
    multicast = values.get("scouting/multicast/enabled")
    if multicast is not False:
        shown = "unset (zenoh's default is true)" if multicast is None else json.dumps(multicast)
        raise ZenohConfigError(
            f"{source}: scouting/multicast/enabled = {shown}; multicast scouting is forbidden "
            "on this network, set it to false and use explicit endpoints"
        )
    listen_key, listen = _for_mode(values.get("listen/endpoints"), "listen/endpoints", role)
    for locator in listen:
        if binds_all_interfaces(locator):
            raise ZenohConfigError(
                f"{source}: {listen_key} contains {locator!r}, which listens on all interfaces; "
                f"listen on {endpoint(LOOPBACK, DEFAULT_PORT)} or a specific address instead"
            )
    if role is ZenohRole.ROUTER and not listen:
        raise ZenohConfigError(f"{source}: {listen_key} is empty; a router must listen")
    connect_key, connect = _for_mode(values.get("connect/endpoints"), "connect/endpoints", role)
    if role is ZenohRole.CLIENT and not connect:
        raise ZenohConfigError(
            f"{source}: {connect_key} is empty; with multicast scouting off a client needs "
            "the router's endpoint"
        )
    exposed = unauthenticated_exposure(values, role)
    if exposed is not None and not allow_unauthenticated:
        raise ZenohConfigError(
            f"{source}: {exposed}, beyond loopback without mutual TLS and access control: "
            "anyone on that network could put setpoints or odometry. Use the TLS configs "
            "(docs/transport-security.md), or set [zenoh] allow_unauthenticated = true to "
            "accept that"
        )
    return role


def shipped_config_path(name: str) -> Path:
    """Path of a shipped config: ``allocator``, ``vessel`` or ``gcs``."""
    if name not in SHIPPED_CONFIGS:
        raise ZenohConfigError(f"zenoh config {name!r}: expected one of {SHIPPED_CONFIGS}")
    return Path(str(resources.files("ftcap_hil").joinpath("data", "zenoh", f"{name}.json5")))


def _role(value: object, what: str) -> ZenohRole:
    if isinstance(value, ZenohRole):
        return value
    try:
        return ZenohRole(value)
    except ValueError:
        known = [r.value for r in ZenohRole]
        raise ZenohConfigError(f"{what} = {value!r}: expected one of {known}") from None


def _for_mode(value: object, key: str, role: ZenohRole) -> tuple[str, list[str]]:
    """Endpoints effective for ``role``: a plain list, or the role's entry of a per-mode map."""
    if isinstance(value, dict):
        key, value = f"{key}/{role.value}", value.get(role.value)
    if value is None:
        return key, []
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ZenohConfigError(f"{key} = {value!r}: expected a list of endpoint strings")
    return key, value


_UNKNOWN_FIELD = re.compile(r"unknown field `([^`]*)`, expected (.*?)(?:\"|, location|$)")
_LOCATION = re.compile(r"line: (\d+), column: (\d+)")


def _tables(tree: Mapping[str, Any], path: str = "") -> Iterator[tuple[str, Mapping[str, Any]]]:
    """Every table of a configuration tree with its ``a/b`` path (``""``: the top)."""
    yield path, tree
    for key, value in tree.items():
        if isinstance(value, dict):
            yield from _tables(value, f"{path}/{key}" if path else key)


def _unknown(key: str, valid: list[str], table: str | None) -> str:
    near = difflib.get_close_matches(key, valid, n=1, cutoff=0.6)
    hint = f" (did you mean {near[0]!r}?)" if near else ""
    where = f"[{table}] " if table else ""
    return f"{where}unknown key {key!r}{hint}; valid keys: {', '.join(sorted(valid))}"


def describe_file_error(source: str, error: str, defaults: Mapping[str, Any]) -> str:
    """``error`` of ``zenoh.Config.from_file`` restated; ``defaults`` is zenoh's default
    configuration as JSON (``str(zenoh.Config())``), where the table is looked up."""
    match = _UNKNOWN_FIELD.search(error)
    if match is None:
        return f"{source}: {error}"
    key, valid = match.group(1), re.findall(r"`([^`]*)`", match.group(2))
    tables = [path or "top" for path, t in _tables(defaults) if set(t) == set(valid)]
    at = _LOCATION.search(error)
    place = f" (line {at.group(1)}, column {at.group(2)})" if at else ""
    table = " or ".join(tables) if tables and tables != ["top"] else None
    return f"{source}: {_unknown(key, valid, table)}{place}"


def describe_override_error(key: str, value: str, error: str, defaults: Mapping[str, Any]) -> str:
    """An override ``key:value`` that zenoh refused with ``error``; for an unknown key, the
    first unknown part of it, its table and the nearest valid key (``defaults`` as for
    :func:`describe_file_error`)."""
    if "unknown key" not in error:
        return f"zenoh config key {key!r} = {value!r}: {error}"
    table: Any = defaults
    parts = key.split("/")
    for i, part in enumerate(parts):
        if not isinstance(table, dict):
            break
        if part not in table:
            return f"--cfg {key}:{value}: {_unknown(part, list(table), '/'.join(parts[:i]))}"
        table = table[part]
    return f"zenoh config key {key!r} = {value!r}: {error}"
