"""Who a MAVLink port listens to and who it sends to: bounded, expiring tables (no I/O).

Every datagram is charged to its source address before it is parsed:

* a **trusted** source (a configured peer or relay inbox, or an address that has sent an
  accepted frame: MAVLink 2, signed when a key is set, from an accepted system id) has its
  own bucket of ``TrafficLimits.peer_rate_hz`` / ``peer_burst`` datagrams;
* any other source is a **stranger**: its own small bucket (``stranger_rate_hz``) and one
  bucket shared by all strangers (``strangers_rate_hz``), so that neither one flooding
  socket nor 10**4 new ports can take the parser away from the trusted sources.

Strangers live in a least-recently-used table of at most ``max_sources`` entries; trusted
sources in a separate table of at most ``max_trusted`` that a flood of new ports cannot
churn, each forgotten ``peer_timeout_s`` after its last accepted frame (configured ones
never). A trusted source that speaks for an authorized (ground-station) system is also a
**reply peer**: it receives everything the port sends, like the configured peers, up to
``max_dynamic_peers`` of them. :class:`PeerTable` hands the sender an immutable snapshot,
so a send never iterates a table that the dispatch thread changes.

Reply slots have a priority, so that a squatter costs only its own slot:

* one slot per MAVLink identity (system, component): the address that claimed it first
  keeps it while it talks; another address with the same identity gets no slot
  (``identity_taken``), unless the holder has been silent for ``takeover_s`` (a restarted
  ground station on a new port takes its identity back within seconds);
* the first ground station admitted is **pinned**: never replaced while it talks;
* a full table makes room only by dropping a peer silent for ``takeover_s`` (never the
  pinned one); otherwise the newcomer is refused (``peers_full``).

Without signing any local process may claim system 255: eight sockets with one identity
now take one slot, eight identities still take eight; a key file is what authenticates.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass, field

Address = tuple[str, int]


@dataclass(frozen=True)
class TrafficLimits:
    """Per-source budgets (datagrams; a datagram of n frames costs n) and table sizes."""

    peer_rate_hz: float = 2000.0
    peer_burst: float = 1000.0
    stranger_rate_hz: float = 20.0
    stranger_burst: float = 20.0
    strangers_rate_hz: float = 400.0
    strangers_burst: float = 400.0
    reply_rate_hz: float = 200.0  # replies (PARAM_VALUE, COMMAND_ACK) bought by one source
    reply_burst: float = 400.0
    max_sources: int = 1024
    max_trusted: int = 32
    max_dynamic_peers: int = 8
    peer_timeout_s: float = 10.0
    takeover_s: float = 3.0  # a reply peer silent this long may lose its slot (1 Hz beats)


@dataclass
class TokenBucket:
    """``rate`` tokens per second up to ``burst``; :meth:`take` may drive it negative by a
    known cost, which later datagrams then pay back."""

    rate: float
    burst: float
    tokens: float = field(init=False)
    last_ns: int | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        self.tokens = self.burst

    def take(self, now_ns: int, cost: float = 1.0) -> bool:
        """Refill to ``now_ns`` and take ``cost`` if at least one token is there."""
        if self.last_ns is not None:
            elapsed = max(0, now_ns - self.last_ns) * 1e-9
            self.tokens = min(self.burst, self.tokens + elapsed * self.rate)
        self.last_ns = now_ns
        if self.tokens < 1.0:
            return False
        self.tokens -= cost
        return True

    def charge(self, cost: float) -> None:
        """Take ``cost`` more without a check (the rest of a datagram already parsed)."""
        self.tokens -= cost


@dataclass
class Source:
    """One trusted source: its budgets, when it was last heard, and whether it is a reply
    peer (``reply``) or configured (``permanent``)."""

    bucket: TokenBucket
    replies: TokenBucket
    last_ns: int = 0
    reply: bool = False
    permanent: bool = False
    identity: tuple[int, int] | None = None  # the (system, component) its slot is held for


@dataclass
class TableStats:
    """What the tables refused or forgot (read by tests and the benchmark)."""

    rate_limited: int = 0  # datagrams dropped unparsed (a source or all strangers over budget)
    replies_limited: int = 0  # replies not sent: the requester's reply budget was spent
    strangers_evicted: int = 0
    trusted_full: int = 0  # accepted frames whose source found no room in the trusted table
    peers_full: int = 0  # authorized sources that found no room among the reply peers
    identity_taken: int = 0  # refused a slot: another address holds that identity
    slots_freed: int = 0  # reply slots taken from a silent peer for a newcomer
    expired: int = 0


@dataclass
class PeerTable:
    """The source tables and the reply-peer snapshot (module docstring).

    ``configured`` peers receive every send; ``relays`` are trusted inboxes that are sent
    only what is relayed to them. Only the dispatch thread calls :meth:`admit_datagram`,
    :meth:`accepted` and :meth:`expire`; any thread may read :attr:`peers`.
    """

    configured: tuple[Address, ...]
    relays: tuple[Address, ...] = ()
    limits: TrafficLimits = field(default_factory=TrafficLimits)
    stats: TableStats = field(default_factory=TableStats)

    def __post_init__(self) -> None:
        self._trusted: dict[Address, Source] = {}
        self._strangers: OrderedDict[Address, TokenBucket] = OrderedDict()
        self._shared = TokenBucket(self.limits.strangers_rate_hz, self.limits.strangers_burst)
        for addr in (*self.configured, *self.relays):
            self._trusted[addr] = self._new_source(permanent=True)
        self._lock = threading.Lock()
        self._snapshot: tuple[Address, ...] = tuple(dict.fromkeys(self.configured))
        self._holders: dict[tuple[int, int], Address] = {}
        self._pinned: Address | None = None

    def _new_source(self, *, permanent: bool = False) -> Source:
        lim = self.limits
        return Source(
            TokenBucket(lim.peer_rate_hz, lim.peer_burst),
            TokenBucket(lim.reply_rate_hz, lim.reply_burst),
            permanent=permanent,
        )

    @property
    def peers(self) -> tuple[Address, ...]:
        """Where a send goes now: the configured peers, then the dynamic reply peers."""
        return self._snapshot

    def dynamic_peers(self) -> tuple[Address, ...]:
        """The reply peers that were learnt, not configured."""
        return tuple(a for a in self._snapshot if a not in self.configured)

    def is_trusted(self, addr: Address) -> bool:
        """``addr`` is configured, a relay, or sent an accepted frame recently."""
        return addr in self._trusted

    def is_relay(self, addr: Address) -> bool:
        """``addr`` is one of the relayed inboxes."""
        return addr in self.relays

    def admit_datagram(self, addr: Address, now_ns: int) -> bool:
        """Charge one datagram from ``addr``; False (counted) if over its budget."""
        source = self._trusted.get(addr)
        if source is not None:
            ok = source.bucket.take(now_ns)
        else:
            bucket = self._strangers.get(addr)
            if bucket is None:
                bucket = TokenBucket(self.limits.stranger_rate_hz, self.limits.stranger_burst)
                self._strangers[addr] = bucket
                if len(self._strangers) > self.limits.max_sources:
                    self._strangers.popitem(last=False)
                    self.stats.strangers_evicted += 1
            else:
                self._strangers.move_to_end(addr)
            ok = bucket.take(now_ns) and self._shared.take(now_ns)
        if not ok:
            self.stats.rate_limited += 1
        return ok

    def charge_frames(self, addr: Address, extra: int) -> None:
        """A datagram held ``extra`` more frames than the one already paid for."""
        if extra <= 0:
            return
        source = self._trusted.get(addr)
        bucket = source.bucket if source is not None else self._strangers.get(addr)
        if bucket is not None:
            bucket.charge(extra)

    def accepted(
        self,
        addr: Address,
        now_ns: int,
        *,
        reply: bool,
        identity: tuple[int, int] | None = None,
    ) -> None:
        """``addr`` sent an accepted frame as ``identity`` (system, component): trust it,
        and give it a reply slot if ``reply`` (it speaks for an authorized system), room
        and priority permitting (module docstring)."""
        source = self._trusted.get(addr)
        if source is None:
            if len(self._trusted) >= self.limits.max_trusted + len(self.configured):
                self.stats.trusted_full += 1
                return
            source = self._new_source()
            self._strangers.pop(addr, None)
            self._trusted[addr] = source
        source.last_ns = now_ns
        if reply and not source.reply and not source.permanent:
            self._admit_reply(addr, source, identity or (0, 0), now_ns)

    def _admit_reply(
        self, addr: Address, source: Source, identity: tuple[int, int], now_ns: int
    ) -> None:
        stale_ns = now_ns - int(self.limits.takeover_s * 1e9)
        holder = self._holders.get(identity)
        if holder is not None and holder != addr:
            held = self._trusted.get(holder)
            if held is not None and held.reply and held.last_ns > stale_ns:
                self.stats.identity_taken += 1
                return
            self._release(holder)  # silent: a restarted ground station takes it back
        if len(self.dynamic_peers()) >= self.limits.max_dynamic_peers:
            silent = [
                a for a, s in self._trusted.items()
                if s.reply and not s.permanent and a != self._pinned and s.last_ns <= stale_ns
            ]  # fmt: skip
            if not silent:
                self.stats.peers_full += 1
                return
            self._release(min(silent, key=lambda a: self._trusted[a].last_ns))
            self.stats.slots_freed += 1
        source.reply, source.identity = True, identity
        self._holders[identity] = addr
        if self._pinned is None:
            self._pinned = addr
        self._publish()

    def _release(self, addr: Address) -> None:
        """``addr`` loses its reply slot (it stays trusted while it talks)."""
        source = self._trusted.get(addr)
        if source is not None and source.reply:
            source.reply = False
            if source.identity is not None and self._holders.get(source.identity) == addr:
                del self._holders[source.identity]
            source.identity = None
        if self._pinned == addr:
            self._pinned = None
        self._publish()

    def take_reply(self, addr: Address | None, now_ns: int, cost: float = 1.0) -> bool:
        """Charge ``cost`` replies to the source that asked; False (counted) if spent."""
        source = self._trusted.get(addr) if addr is not None else None
        if source is None:
            return True  # our own initiative (no requester), or a requester just forgotten
        if source.replies.take(now_ns, cost):
            return True
        self.stats.replies_limited += 1
        return False

    def expire(self, now_ns: int) -> None:
        """Forget learnt sources not heard from for ``peer_timeout_s``."""
        horizon = now_ns - int(self.limits.peer_timeout_s * 1e9)
        stale = [a for a, s in self._trusted.items() if not s.permanent and s.last_ns < horizon]
        for addr in stale:
            self._release(addr)
            self._trusted.pop(addr)
            self.stats.expired += 1

    def _publish(self) -> None:
        dynamic = [a for a, s in self._trusted.items() if s.reply and not s.permanent]
        with self._lock:
            self._snapshot = tuple(dict.fromkeys((*self.configured, *dynamic)))

    def sizes(self) -> tuple[int, int]:
        """(strangers, trusted) entries held now."""
        return len(self._strangers), len(self._trusted)
