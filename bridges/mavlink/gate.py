"""The receive side of a MAVLink port: what a datagram must pass before a handler sees it.

For each datagram (dispatch thread only):

1. its source pays one token (:meth:`PeerTable.admit_datagram`), else it is dropped
   unparsed (``rate_limited``); a datagram over 2 KiB (seven maximal frames) is dropped
   unparsed (``oversized``);
2. it is parsed, the parser reset after it (a frame never spans datagrams; an incomplete
   tail is ``bad_data``), and each frame beyond the first costs one more token;
3. each frame is refused, and counted by reason, if it is MAVLink 1 (``mavlink1``), unsigned
   or badly signed or replayed while a key is set (``unsigned``, ``bad_signature``,
   ``replay``), or from a system id that is neither ours nor authorized (``unknown_system``);
4. an accepted frame makes its source trusted, and a reply peer if it speaks for an
   authorized system;
5. relaying: an accepted frame from a learnt reply peer that is not addressed to this
   component alone goes on, byte for byte (signature included), to the relay inboxes; any
   accepted frame from a relay inbox goes on to the learnt reply peers.

Everything dropped is counted in :class:`PortStats` or the table's
:class:`~bridges.mavlink.peers.TableStats`; nothing here raises for bad input.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from bridges.mavlink.peers import Address
from bridges.mavlink.signing import SignatureVerifier, signing_timestamp
from bridges.mavlink.transport import StreamTransport, UdpTransport

MAX_PARSED_DATAGRAM = 2048
_REASONS = ("mavlink1", "unsigned", "bad_signature", "replay", "unknown_system")


@dataclass
class PortStats:
    """Counters of one port, written by its dispatch thread (``send_errors`` by senders)."""

    datagrams: int = 0  # datagrams (or stream reads) the gate was handed
    parsed: int = 0  # of those, the ones parsed (not rate-limited or oversized)
    received: int = 0  # frames accepted by the gate
    bad_data: int = 0  # CRC errors, garbage bytes, incomplete frames, empty datagrams
    oversized: int = 0
    mavlink1: int = 0
    unsigned: int = 0
    bad_signature: int = 0
    replay: int = 0
    unknown_system: int = 0
    unauthorized: int = 0  # setpoints / parameters / commands from a non-authorized system
    wrong_source: int = 0  # telemetry from an address that is not the vessel's inbox
    malformed: int = 0  # decoded but invalid, for handlers without a mailbox
    ignored: int = 0  # addressed to someone else, from an unexpected source, or our own echo
    relayed: int = 0
    send_errors: int = 0
    errors: int = 0  # unexpected exceptions in handlers (logged)

    def refused(self) -> int:
        """Frames the gate refused (MAVLink 1, signing, unknown systems)."""
        return sum(getattr(self, r) for r in _REASONS)

    def frames_counted(self) -> int:
        """Every outcome of a parsed datagram: accepted, refused, bad or our own echo."""
        return self.received + self.bad_data + self.refused() + self.ignored


class InboxGate:
    """Steps 1-5 of the module docstring for one port."""

    def __init__(
        self,
        dialect: ModuleType,
        transport: UdpTransport | StreamTransport,
        own_ids: tuple[int, int],
        authorized: frozenset[int],
        verifier: SignatureVerifier | None,
        stats: PortStats,
        *,
        datagrams: bool = True,
    ) -> None:
        self._dialect = dialect
        self._transport = transport
        self._table = transport.table
        self._own = own_ids
        self._authorized = authorized
        self._accepted_systems = authorized | {own_ids[0]}
        self._verifier = verifier
        self._stats = stats
        self._datagrams = datagrams
        self.parser = dialect.MAVLink(None, srcSystem=own_ids[0], srcComponent=own_ids[1])
        self.parser.robust_parsing = True

    def process(self, data: bytes, addr: Address, now_ns: int) -> list[Any]:
        """The accepted messages of one datagram (or stream read) from ``addr``."""
        table = self._table
        self._stats.datagrams += 1
        if not table.admit_datagram(addr, now_ns):
            return []
        if self._datagrams and len(data) > MAX_PARSED_DATAGRAM:
            self._stats.oversized += 1
            return []
        self._stats.parsed += 1
        msgs = self._parse(data)
        if not msgs and self._datagrams and not data:
            self._stats.bad_data += 1  # an empty datagram: nothing else would count it
        table.charge_frames(addr, len(msgs) - 1)
        out = []
        signing_now = signing_timestamp(time.time()) if self._verifier is not None else 0
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                self._stats.bad_data += 1
                continue
            reason = self._refusal(msg, signing_now)
            if reason:
                setattr(self._stats, reason, getattr(self._stats, reason) + 1)
                continue
            system = msg.get_srcSystem()
            if (system, msg.get_srcComponent()) == self._own:
                self._stats.ignored += 1  # our own traffic echoed back by a forwarder
                continue
            self._stats.received += 1
            table.accepted(
                addr, now_ns, reply=system in self._authorized,
                identity=(system, msg.get_srcComponent()),
            )  # fmt: skip
            self._relay(msg, addr)
            out.append(msg)
        return out

    def _parse(self, data: bytes) -> list[Any]:
        parser = self.parser
        try:
            msgs: list[Any] = parser.parse_buffer(data) or []
        except Exception:  # robust parsing should never raise; if it does, the input is bad
            self._stats.bad_data += 1
            self._reset_parser()
            return []
        if self._datagrams and parser.buf_len() > 0:
            # A frame never spans datagrams: drop the incomplete tail, or a bogus length
            # field in garbage would swallow the next, valid datagram.
            self._stats.bad_data += 1
            self._reset_parser()
        return msgs

    def _reset_parser(self) -> None:
        parser = self.parser
        parser.buf, parser.buf_index = bytearray(), 0
        parser.expected_length = self._dialect.HEADER_LEN_V1 + 2  # as in MAVLink.__init__

    def _refusal(self, msg: Any, signing_now: int) -> str:
        msgbuf = msg.get_msgbuf()
        if not msgbuf or msgbuf[0] != self._dialect.PROTOCOL_MARKER_V2:
            return "mavlink1"
        system, component = msg.get_srcSystem(), msg.get_srcComponent()
        if self._verifier is not None:
            reason = self._verifier.check(msgbuf, system, component, signing_now)
            if reason:
                return reason
        if system not in self._accepted_systems:
            return "unknown_system"
        return ""

    def _stays_here(self, msg: Any) -> bool:
        system = getattr(msg, "target_system", getattr(msg, "target", None))
        component = getattr(msg, "target_component", None)
        if system is None or system == 0:
            return False  # a broadcast: for the relayed components too
        if system != self._own[0]:
            return True  # another vehicle's: not for the components behind us either
        return component == self._own[1]

    def _relay(self, msg: Any, addr: Address) -> None:
        table, transport = self._table, self._transport
        if table.is_relay(addr):
            targets = table.dynamic_peers()
        elif addr in table.dynamic_peers() and not self._stays_here(msg):
            targets = table.relays
        else:
            return
        raw = msg.get_msgbuf()
        for target in targets:
            if transport.send_to(raw, target):
                self._stats.relayed += 1
