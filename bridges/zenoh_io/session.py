"""The Zenoh session under every ftcap link: checked configs and the shared link lifecycle.

:class:`ZenohLink` owns one session opened from a checked config (see
:mod:`bridges.zenoh_io.config`), declares publishers and subscribers once, and is closed by an
idempotent ``shutdown()`` (or by leaving its ``with`` block). Subscriber callbacks run on
zenoh-python's threads, only decode, then ``put`` into a
:class:`~ftcap_hil.ports.mailbox.Mailbox` (or an ``EventQueue``); a payload that fails to
decode is counted there (``malformed``) and dropped, never raised. Publishing returns False
instead of raising when encoding or the session fails, so the caller's loop can mark the port
stale and carry on; failures are logged on transitions only. The role links built on it are
in :mod:`bridges.zenoh_io.link`; this package is the only place that imports zenoh.
"""

from __future__ import annotations

import atexit
import functools
import json
import logging
import threading
import time
import weakref
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol, Self, TypeVar

import zenoh

from bridges.zenoh_io.codec import ZenohKeys
from bridges.zenoh_io.config import (
    CHECKED_KEYS,
    DEFAULT_PORT,
    LOOPBACK,
    ZenohConfigError,
    ZenohRole,
    check_settings,
    describe_file_error,
    describe_override_error,
    parse_override,
    role_settings,
    shipped_config_path,
    unauthenticated_exposure,
)
from bridges.zenoh_io.ros2.endpoints import (
    Ros2Endpoint,
    Ros2Node,
    Ros2Publisher,
    Ros2Settings,
)
from ftcap_hil.core.errors import MalformedMessage, PortError
from ftcap_hil.core.status import Severity
from ftcap_hil.ports.transitions import TransitionLog, log_to

log = logging.getLogger(__name__)
T = TypeVar("T")
T_contra = TypeVar("T_contra", contravariant=True)
JSON_ENCODING = zenoh.Encoding.APPLICATION_JSON
LOG_INTERVAL_S = 5.0  # at most one failing/working line per port and interval


class ZenohLinkError(PortError):
    """The session could not be opened (router unreachable, port taken, ...)."""


# --------------------------------------------------------------------------- configuration


def apply_overrides(conf: zenoh.Config, overrides: Sequence[str] | Mapping[str, str]) -> None:
    """Insert ``KEY:VALUE`` strings (as zenoh examples' ``--cfg``) or a key -> JSON5 mapping."""
    pairs = overrides.items() if isinstance(overrides, Mapping) else map(parse_override, overrides)
    for key, value in pairs:
        try:
            conf.insert_json5(key, value)
        except zenoh.ZError as e:
            raise ZenohConfigError(describe_override_error(key, value, str(e), _defaults())) from e


def validate_config(
    conf: zenoh.Config, source: str = "zenoh config", allow_unauthenticated: bool = False,
) -> ZenohRole:  # fmt: skip
    """Apply :func:`bridges.zenoh_io.config.check_settings` to a zenoh.Config; return its
    role. An unauthenticated endpoint beyond loopback that ``allow_unauthenticated`` lets
    through is logged as a warning."""
    values = {key: _get_json(conf, key) for key in CHECKED_KEYS}
    role = check_settings(values, source, allow_unauthenticated)
    exposed = unauthenticated_exposure(values, role)
    if exposed is not None:
        log.warning(
            "%s: %s, beyond loopback without authentication (allow_unauthenticated = true): "
            "anyone on that network can put setpoints or odometry", source, exposed,
        )  # fmt: skip
    return role


def make_config(
    role: ZenohRole | str,
    port: int = DEFAULT_PORT,
    host: str = LOOPBACK,
    overrides: Sequence[str] = (),
) -> zenoh.Config:
    """A checked config: a router listening on ``tcp/host:port`` or a client/peer connecting."""
    conf = zenoh.Config()
    apply_overrides(conf, role_settings(role, port, host))
    apply_overrides(conf, overrides)
    validate_config(conf, f"{ZenohRole(role).value} config")
    return conf


def load_config(
    path: str | Path, overrides: Sequence[str] = (), allow_unauthenticated: bool = False,
) -> zenoh.Config:  # fmt: skip
    """Load a JSON5 file, apply ``KEY:VALUE`` overrides, check it (``allow_unauthenticated``:
    :func:`validate_config`); ZenohConfigError if bad."""
    conf = _read(path, overrides)
    validate_config(conf, f"zenoh config {path}", allow_unauthenticated)
    return conf


def check_config_file(
    path: str | Path,
    overrides: Sequence[str] = (),
    allow_unauthenticated: bool = False,
) -> None:
    """:func:`load_config`'s checks alone, nothing logged: a configuration reader's, so that
    a refused file stops the start before any port is opened."""
    conf = _read(path, overrides)
    values = {key: _get_json(conf, key) for key in CHECKED_KEYS}
    check_settings(values, f"zenoh config {path}", allow_unauthenticated)


def _read(path: str | Path, overrides: Sequence[str]) -> zenoh.Config:
    try:
        conf = zenoh.Config.from_file(str(path))
    except zenoh.ZError as e:
        message = describe_file_error(f"zenoh config file {path}", str(e), _defaults())
        raise ZenohConfigError(message) from e
    apply_overrides(conf, overrides)
    return conf


@functools.cache
def _defaults() -> dict[str, Any]:
    """zenoh's default configuration as JSON (where error messages look tables up; {} if
    this zenoh prints its Config otherwise: the messages then name no table)."""
    try:
        defaults = json.loads(str(zenoh.Config()))
    except ValueError:
        return {}
    return defaults if isinstance(defaults, dict) else {}


def authenticates(conf: zenoh.Config) -> bool:
    """The session admits peers by identity: access control on, default deny (the TLS
    configs: only the vessel's certificate may put odometry). Without it any process that
    reaches the router may publish on any key."""
    enabled = _get_json(conf, "access_control/enabled")
    default = _get_json(conf, "access_control/default_permission")
    return enabled is True and default == "deny"


def _get_json(conf: zenoh.Config, key: str) -> Any:
    try:
        return json.loads(conf.get_json(key))
    except zenoh.ZError:
        return None


def _debug(text: str, _severity: Severity) -> None:
    """Where a port's changes held back by :data:`LOG_INTERVAL_S` go."""
    log.debug("%s", text)


def _matched(publisher: zenoh.Publisher) -> bool:
    # typed bool in the stubs, but zenoh 1.x returns a MatchingStatus (always truthy)
    status = publisher.matching_status
    return bool(getattr(status, "matching", status))


# --------------------------------------------------------------------------- sinks


class _Sink(Protocol[T_contra]):
    """Where a subscriber's decoded samples go: a Mailbox or an EventQueue."""

    def put(self, value: T_contra, stamp_ns: int | None = None) -> None:
        """Take one decoded sample."""

    def count_malformed(self) -> None:
        """Count one sample that failed to decode."""


# --------------------------------------------------------------------------- lifecycle

# Links still open at exit are shut down before the interpreter joins zenoh's non-daemon
# callback threads, which would otherwise hang it (docs/decisions.md).
_OPEN_LINKS: weakref.WeakSet[ZenohLink] = weakref.WeakSet()


def _shutdown_open_links() -> None:
    for link in list(_OPEN_LINKS):
        link.shutdown()


getattr(threading, "_register_atexit", atexit.register)(_shutdown_open_links)


class ZenohLink:
    """Session lifecycle shared by the three links: open, declare, publish, shutdown.

    ``vessel``: the key chunk of ``ftcap/<vessel>/...``; ``config``: a zenoh.Config (checked
    here), or None for the role's shipped JSON5 file. ZenohLinkError if the session cannot be
    opened, ZenohConfigError if the config is refused.
    """

    _shipped: str = ""

    def __init__(self, vessel: str, config: zenoh.Config | None) -> None:
        self.keys = ZenohKeys.for_vessel(vessel)
        if config is None:
            config = load_config(shipped_config_path(self._shipped))
        else:
            validate_config(config, f"{type(self).__name__} config")
        self.publish_errors = 0
        self.decode_errors = 0  # samples a decoder failed on with other than MalformedMessage
        self._entities: list[Any] = []
        self._publishers: dict[str, zenoh.Publisher] = {}
        # a port whose last message failed is on; a port that keeps flipping logs one line
        # per LOG_INTERVAL_S, the changes in between at debug level
        self._failing = TransitionLog(log_to(log), min_interval_s=LOG_INTERVAL_S, quiet=_debug)
        self._closed = False
        self._close_lock = threading.Lock()
        try:
            self._session = zenoh.open(config)
        except zenoh.ZError as e:
            raise ZenohLinkError(f"{type(self).__name__}: cannot open zenoh session: {e}") from e
        _OPEN_LINKS.add(self)

    def _subscribe(self, key: str, decode: Callable[[bytes], T], sink: _Sink[T]) -> None:
        def on_sample(sample: zenoh.Sample) -> None:
            if sample.kind != zenoh.SampleKind.PUT:  # pyo3 enums: `is` is always False
                return
            try:
                value = decode(sample.payload.to_bytes())
            except MalformedMessage as e:
                sink.count_malformed()
                self._transition(key, failed=True, detail=f"dropped malformed sample: {e}")
                return
            except Exception as e:  # noqa: BLE001 - a callback must never raise into zenoh
                # A decoder bug, not the sender's: still counted and dropped, never a
                # traceback per sample; the type is named once (log on transition).
                sink.count_malformed()
                self.decode_errors += 1
                detail = f"dropped undecodable sample ({type(e).__name__}: {e!s:.120})"
                self._transition(key, failed=True, detail=detail)
                return
            sink.put(value)
            if self._failing[key]:
                self._transition(key, failed=False, detail="valid samples again")

        self._entities.append(self._session.declare_subscriber(key, on_sample))

    def _declare_publisher(
        self,
        key: str,
        *,
        urgent: bool = False,
        reliable: bool = False,
        encoding: zenoh.Encoding = JSON_ENCODING,
    ) -> None:
        """urgent: real-time priority, no batching, drop when congested (latest value wins)."""
        if urgent:
            priority, express = zenoh.Priority.REAL_TIME, True
        else:
            priority, express = zenoh.Priority.DATA, False
        congestion = zenoh.CongestionControl.BLOCK if reliable else zenoh.CongestionControl.DROP
        publisher = self._session.declare_publisher(
            key,
            encoding=encoding,
            priority=priority,
            express=express,
            congestion_control=congestion,
        )
        self._publishers[key] = publisher
        self._entities.append(publisher)

    def _publish(self, key: str, encode: Callable[[T], bytes], msg: T) -> bool:
        try:
            payload = encode(msg)
        except (ValueError, TypeError) as e:  # MalformedMessage is a ValueError
            self._fail(key, f"cannot encode: {e}")
            return False
        return self._put(key, payload)

    def _put(self, key: str, payload: bytes, attachment: bytes | None = None) -> bool:
        if self._closed:
            return False
        try:
            self._publishers[key].put(payload, attachment=attachment)
        except zenoh.ZError as e:
            self._fail(key, f"publish failed: {e}")
            return False
        if self._failing[key]:
            self._transition(key, failed=False, detail="publishing again")
        return True

    # --- the ROS 2 mapping (bridges.zenoh_io.ros2): rmw_zenoh's keys, tokens, attachments

    def _ros2_node(self, name: str, settings: Ros2Settings) -> Ros2Node:
        """Declare the liveliness token of node ``name`` and return it, for its endpoints."""
        namespace = settings.namespace_for(self.keys.vessel)
        node = Ros2Node(settings.domain_id, str(self._session.zid()), namespace, name)
        self._entities.append(self._session.liveliness().declare_token(node.token()))
        return node

    def _ros2_publisher(self, node: Ros2Node, topic: str, type_name: str) -> Ros2Publisher:
        """A publisher as rmw_zenoh declares one: its token, its key (no encoding set)."""
        pub = node.publisher(topic, type_name)
        self._declare_publisher(pub.key, urgent=True, encoding=zenoh.Encoding.ZENOH_BYTES)
        self._entities.append(self._session.liveliness().declare_token(pub.token))
        return pub

    def _ros2_subscribe(
        self,
        node: Ros2Node,
        topic: str,
        type_name: str,
        convert: Callable[[Any], T],
        sink: _Sink[T],
    ) -> Ros2Endpoint:
        """A subscription: its token, and samples ``convert``ed into ``sink``."""
        sub = node.subscription(topic, type_name)
        self._subscribe(sub.key, sub.decoder(convert), sink)
        self._entities.append(self._session.liveliness().declare_token(sub.token))
        return sub

    def _publish_ros2(self, pub: Ros2Publisher, value: dict[str, Any]) -> bool:
        """One sample: CDR payload and rmw_zenoh's attachment; False if it cannot be sent."""
        try:
            payload = pub.encode(value)
        except (ValueError, TypeError, KeyError) as e:
            self._fail(pub.key, f"cannot encode {pub.type_name}: {e}")
            return False
        return self._put(pub.key, payload, pub.next_attachment(time.time_ns()))

    def _fail(self, key: str, detail: str) -> None:
        self.publish_errors += 1
        self._transition(key, failed=True, detail=detail)

    def _transition(self, key: str, *, failed: bool, detail: str) -> None:
        """Log a port's change between failing and working; a port that keeps flipping
        (valid and malformed samples interleaved) logs at most once per
        :data:`LOG_INTERVAL_S`, the next line saying how many changes it did not log."""
        text = f"{key}: {detail}"
        if not self._failing.update(key, failed, text, text):
            log.debug("%s", text)

    def subscribers_matched(self, key: str | None = None, timeout_s: float = 0.0) -> bool:
        """True once the publisher on ``key`` (None: every publisher of this link) has a
        matching remote subscriber; waits up to ``timeout_s``.

        A sample published before the match can be lost, so a process that must not lose
        its first message waits on this first.
        """
        publishers = list(self._publishers.values()) if key is None else [self._publishers[key]]
        deadline = time.monotonic() + timeout_s
        while True:
            if not self._closed and all(map(_matched, publishers)):
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)

    @property
    def closed(self) -> bool:
        """``shutdown()`` has run."""
        return self._closed

    def shutdown(self) -> None:
        """Undeclare everything and close the session; safe to call more than once."""
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        _OPEN_LINKS.discard(self)
        for entity in reversed(self._entities):
            try:
                entity.undeclare()
            except zenoh.ZError as e:
                log.debug("undeclare %s: %s", entity, e)
        self._entities.clear()
        try:
            self._session.close()
        except zenoh.ZError as e:
            log.warning("closing zenoh session: %s", e)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()
