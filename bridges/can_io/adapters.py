"""DroneCAN-over-python-can adapters: the allocator's and the simulated vessel's CAN ports.

Allocator side (node ``node_id``, default 10):

* ``CanThrusterSink``: ``send(u)`` -> one ``esc.RawCommand`` transfer (all thrusters);
  ``tick()`` -> own ``NodeStatus`` at 1 Hz; the loop thread calls both. With
  ``start_stream()`` the latest command is also re-sent at the ESCs' rate (``esc_stream.py``).
* ``CanEscStatusSource``: Notifier callback; ``esc.Status`` -> ``EscStatus`` into one
  ``Mailbox`` per thruster (``esc_index`` = thruster index). An ESC whose mailbox ages is the
  loop's to declare failed.

Vessel side (one node per ESC, ``esc_node_ids[i]`` plays ESC ``i``):

* ``CanCommandSource``: ``esc.RawCommand`` -> ``ThrusterCommand`` (N) into a ``Mailbox``.
* ``CanEscStatusSink``: ``send(EscStatus)`` -> ``esc.Status``; ``tick()`` -> ESC NodeStatus.

Adapters never own the bus unless ``owns_bus=True``; each is a context manager with an
idempotent ``shutdown()``. Sources create their own ``can.Notifier`` or join a given one
(python-can allows one Notifier per bus). Callbacks only decode, validate and ``put``;
malformed input is counted and dropped. Send failures are counted, mark the port ``stale``
(logged on transitions only) and return False: the loop carries on.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Sequence

import can
import numpy as np

from bridges.can_io.codec import (
    PRIORITY_HIGH,
    PRIORITY_LOWEST,
    PRIORITY_MEDIUM,
    DataType,
    EscStatusMsg,
    Health,
    Mode,
    NodeStatusMsg,
    RawCommandMsg,
    Received,
    check_node_id,
    check_node_ids,
)
from bridges.can_io.esc_stream import (
    DEFAULT_ESC_TIMEOUT_S,
    DEFAULT_HOLD_S,
    DEFAULT_RATE_HZ,
    EscCommandStream,
)
from bridges.can_io.follower import CommandFollower
from bridges.can_io.force_map import ForceMap
from bridges.can_io.node import ConflictDetector
from bridges.can_io.ports import CanReceiver, CanSender
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import EscStatus, ThrusterCommand
from ftcap_hil.ports.mailbox import Mailbox, Stamped

DEFAULT_ALLOCATOR_NODE_ID = 10


class CanThrusterSink(CanSender):
    """Allocator -> ESCs: per-thruster forces as one ``esc.RawCommand`` transfer."""

    def __init__(
        self,
        bus: can.BusABC,
        force_map: ForceMap,
        *,
        node_id: int = DEFAULT_ALLOCATOR_NODE_ID,
        priority: int = PRIORITY_HIGH,
        status_period_s: float = 1.0,
        send_timeout_s: float = 0.002,
        zero_on_shutdown: bool = True,
        owns_bus: bool = False,
    ) -> None:
        super().__init__(bus, owns_bus, "CanThrusterSink", send_timeout_s, status_period_s)
        self.force_map = force_map
        self.node_id = check_node_id("node_id", node_id)
        self._priority = priority
        self._zero_on_shutdown = zero_on_shutdown
        self.health = Health.OK
        self.mode = Mode.OPERATIONAL
        self.last_raw: tuple[int, ...] | None = None
        self.stream: EscCommandStream | None = None

    def start_stream(
        self,
        rate_hz: float = DEFAULT_RATE_HZ,
        hold_s: float = DEFAULT_HOLD_S,
        *,
        esc_timeout_s: float = DEFAULT_ESC_TIMEOUT_S,
        restart_from_zero: bool = False,
    ) -> EscCommandStream:
        """Re-send the latest command every ``1 / rate_hz`` s (1..400 Hz) from a thread;
        zero once no ``send`` came for ``hold_s`` or no command reached the bus for
        ``esc_timeout_s`` (the ESCs' own timeout), held until the next ``send`` or, with
        ``restart_from_zero``, until ``take_lapse()`` (``esc_stream.py``). Stopped by
        ``shutdown()``. Once only."""
        if self.stream is not None:
            raise RuntimeError("CanThrusterSink: the ESC stream is already running")
        zero = (0,) * self.force_map.m
        self.stream = EscCommandStream(
            self.send_raw, zero, rate_hz=rate_hz, hold_s=hold_s, esc_timeout_s=esc_timeout_s,
            restart_from_zero=restart_from_zero,
        )  # fmt: skip
        return self.stream.start()

    def take_lapse(self) -> bool:
        """True if the ESCs may have dropped to zero since the last call (the stream's
        lapse: bus down, this process stalled, or no allocation for ``hold_s``): restart the
        command from zero. Always False without a stream."""
        return self.stream is not None and self.stream.take_lapse()

    def send(self, u: Sequence[float] | np.ndarray) -> bool:
        """Send forces ``u`` (m,) in N now (and hold them in the ESC stream, if running;
        during a lapse the stream may send zero instead). Raises ``NonFiniteCommand`` for
        NaN/inf (nothing sent, nothing held).

        Returns False (and marks the port stale) if the bus refused the frames.
        """
        raw = self.force_map.to_raw(u)
        if self.stream is not None:
            return self.stream.update(tuple(int(v) for v in raw))
        return self.send_raw(raw)

    def send_zero(self) -> bool:
        """Command zero force on every thruster (raw 0); False if the bus refused it."""
        return self.send(np.zeros(self.force_map.m))

    def send_raw(self, raw: Sequence[int] | np.ndarray) -> bool:
        """Send raw int14 values directly (length m, clipped to +-8191 by the codec)."""
        values = tuple(int(v) for v in raw)
        if len(values) != self.force_map.m:
            raise ValueError(f"raw command: expected {self.force_map.m} values, got {len(values)}")
        ok = self._send(RawCommandMsg(values), self.node_id, DataType.RAW_COMMAND, self._priority)
        if ok:
            self.last_raw = values
        return ok

    def set_status(self, health: Health, mode: Mode = Mode.OPERATIONAL) -> None:
        """Health and mode reported in the next NodeStatus."""
        self.health, self.mode = health, mode

    def current_status(self, node_id: int | None = None) -> NodeStatusMsg:
        """This node's NodeStatus now (uptime, health, mode); what GetNodeInfo reports."""
        return NodeStatusMsg(self._uptime_s(), self.health, self.mode)

    def tick(self, now_ns: int | None = None) -> bool:
        """Send NodeStatus if one is due (first call: now). True if one was sent."""
        if not self._status_due(now_ns):
            return False
        return self._send_node_status(self.mode)

    def _send_node_status(self, mode: Mode) -> bool:
        msg = NodeStatusMsg(self._uptime_s(), self.health, mode)
        return self._send(msg, self.node_id, DataType.NODE_STATUS, PRIORITY_LOWEST)

    def _close(self) -> None:
        if self.stream is not None:
            self.stream.stop()
        if self._zero_on_shutdown:
            # The last writes: command zero, then announce that this node goes offline.
            self.send_raw(np.zeros(self.force_map.m, dtype=np.int64))
            self._send_node_status(Mode.OFFLINE)


class CanEscStatusSink(CanSender):
    """Simulated ESCs -> bus: ``esc.Status`` from node ``esc_node_ids[index]``."""

    def __init__(
        self,
        bus: can.BusABC,
        esc_node_ids: Sequence[int],
        *,
        priority: int = PRIORITY_MEDIUM,
        status_period_s: float = 1.0,
        send_timeout_s: float = 0.002,
        owns_bus: bool = False,
    ) -> None:
        super().__init__(bus, owns_bus, "CanEscStatusSink", send_timeout_s, status_period_s)
        self.esc_node_ids = check_node_ids("esc_node_ids", esc_node_ids)
        if not 1 <= len(self.esc_node_ids) <= 32 or len(set(self.esc_node_ids)) != len(
            self.esc_node_ids
        ):
            raise ValueError(f"esc_node_ids: need 1..32 distinct node IDs, got {esc_node_ids}")
        self._priority = priority

    def send(
        self, status: EscStatus, *, temperature_k: float = math.nan, power_rating_pct: int = 0
    ) -> bool:
        """One ``esc.Status`` for ESC ``status.index``. ``rpm`` must be finite."""
        if not 0 <= status.index < len(self.esc_node_ids):
            raise ValueError(
                f"EscStatus.index {status.index} outside 0..{len(self.esc_node_ids) - 1}"
            )
        if not math.isfinite(status.rpm):
            raise ValueError(f"EscStatus.rpm must be finite, got {status.rpm}")
        msg = EscStatusMsg(
            esc_index=status.index,
            rpm=round(status.rpm),
            current_a=status.current_a,
            voltage_v=status.voltage_v,
            temperature_k=temperature_k,
            error_count=status.error_count,
            power_rating_pct=power_rating_pct,
        )
        node_id = self.esc_node_ids[status.index]
        return self._send(msg, node_id, DataType.ESC_STATUS, self._priority)

    def send_all(self, statuses: Iterable[EscStatus]) -> bool:
        """Send each; True only if all went out."""
        return all([self.send(s) for s in statuses])

    def current_status(self, node_id: int | None = None) -> NodeStatusMsg:
        """A simulated ESC's NodeStatus now (uptime, health OK, operational)."""
        return NodeStatusMsg(self._uptime_s())

    def tick(self, now_ns: int | None = None, indices: Iterable[int] | None = None) -> bool:
        """NodeStatus for the ESCs in ``indices`` (default all) if due. True if sent."""
        if not self._status_due(now_ns):
            return False
        chosen = range(len(self.esc_node_ids)) if indices is None else indices
        msg = NodeStatusMsg(self._uptime_s())
        sent = [
            self._send(msg, self.esc_node_ids[i], DataType.NODE_STATUS, PRIORITY_LOWEST)
            for i in chosen
        ]
        return all(sent)


class CanEscStatusSource(CanReceiver):
    """Bus -> allocator: ``esc.Status`` into ``mailboxes[esc_index]`` as ``EscStatus``.

    With ``esc_node_ids`` given, a status is accepted only from the node configured for its
    index (others count as malformed). NodeStatus of every node seen is kept too.
    """

    def __init__(
        self,
        bus: can.BusABC,
        n_thrusters: int,
        *,
        esc_node_ids: Sequence[int] | None = None,
        notifier: can.Notifier | None = None,
        poll_timeout_s: float = 0.1,
        owns_bus: bool = False,
    ) -> None:
        if not 1 <= n_thrusters <= 32:
            raise ValueError(f"n_thrusters: need 1..32, got {n_thrusters}")
        if esc_node_ids is not None:
            esc_node_ids = check_node_ids("esc_node_ids", esc_node_ids)
            if len(esc_node_ids) != n_thrusters:
                raise ValueError(f"esc_node_ids: need {n_thrusters} IDs, got {len(esc_node_ids)}")
        self._esc_node_ids = None if esc_node_ids is None else tuple(esc_node_ids)
        self.mailboxes: tuple[Mailbox[EscStatus], ...] = tuple(
            Mailbox(f"esc{i}") for i in range(n_thrusters)
        )
        self._node_status: dict[int, Mailbox[NodeStatusMsg]] = {}
        super().__init__(
            bus,
            owns_bus,
            "CanEscStatusSource",
            (DataType.ESC_STATUS, DataType.NODE_STATUS),
            notifier,
            poll_timeout_s,
        )

    def _handle(self, got: Received, now_ns: int) -> None:
        msg = got.message
        if isinstance(msg, NodeStatusMsg):
            box = self._node_status.setdefault(
                got.source_node_id, Mailbox(f"node{got.source_node_id}")
            )
            box.put(msg, now_ns)
            return
        if not isinstance(msg, EscStatusMsg):
            return
        if msg.esc_index >= len(self.mailboxes) or (
            self._esc_node_ids is not None
            and self._esc_node_ids[msg.esc_index] != got.source_node_id
        ):
            raise MalformedMessage(
                f"esc.Status index {msg.esc_index} from node {got.source_node_id}"
            )
        status = EscStatus(
            msg.esc_index, float(msg.rpm), msg.current_a, msg.voltage_v, msg.error_count
        )
        self.mailboxes[msg.esc_index].put(status, now_ns)

    def ages_s(self, now_ns: int | None = None) -> np.ndarray:
        """(m,) seconds since each ESC last reported; +inf for never."""
        now = time.monotonic_ns() if now_ns is None else now_ns
        return np.array([box.age_s(now) for box in self.mailboxes])

    def node_status(self, node_id: int) -> Stamped[NodeStatusMsg] | None:
        """Latest NodeStatus heard from ``node_id``, or None."""
        box = self._node_status.get(node_id)
        return None if box is None else box.latest()


class CanCommandSource(CanReceiver):
    """Bus -> vessel: ``esc.RawCommand`` from the allocator node as ``ThrusterCommand`` (N).

    ``allocator_node_id=None`` accepts commands from any node. A command whose length is not
    ``force_map.m`` is malformed. The allocator's NodeStatus lands in ``allocator_status``.
    ``conflict`` watches the allocator's node ID for a second sender (``node.py``).

    A RawCommand is obeyed only if it continues the stream being followed (``follower``,
    :class:`~bridges.can_io.follower.CommandFollower`: transfer IDs in sequence, a changed
    command confirmed by the next frame while the ID is suspicious, zero at once when two
    senders share one sequence); ``obey_in_conflict`` turns that off.
    ``dropped_in_conflict``: commands dropped while a conflict was on.
    """

    def __init__(
        self,
        bus: can.BusABC,
        force_map: ForceMap,
        *,
        allocator_node_id: int | None = DEFAULT_ALLOCATOR_NODE_ID,
        notifier: can.Notifier | None = None,
        poll_timeout_s: float = 0.1,
        obey_in_conflict: bool = False,
        owns_bus: bool = False,
        resync_s: float = 0.05,
    ) -> None:
        if allocator_node_id is not None:
            check_node_id("allocator_node_id", allocator_node_id)
        self.force_map = force_map
        self._allocator = allocator_node_id
        self.commands: Mailbox[ThrusterCommand] = Mailbox("can_thruster_command")
        # The same, put only when the value changes: stamped when a command first came, not
        # when the ESC stream last repeated it (when it took effect on a real thruster).
        self.changes: Mailbox[ThrusterCommand] = Mailbox("can_thruster_command_change")
        self.raw_commands: Mailbox[tuple[int, ...]] = Mailbox("can_raw_command")
        self._last_raw: tuple[int, ...] | None = None
        self.allocator_status: Mailbox[NodeStatusMsg] = Mailbox("can_allocator_status")
        self.conflict = None if allocator_node_id is None else ConflictDetector(allocator_node_id)
        self._obey_in_conflict = obey_in_conflict
        self.dropped_in_conflict = 0
        self.follower = CommandFollower(resync_s)
        super().__init__(
            bus,
            owns_bus,
            "CanCommandSource",
            (DataType.RAW_COMMAND, DataType.NODE_STATUS),
            notifier,
            poll_timeout_s,
        )

    def _handle(self, got: Received, now_ns: int) -> None:
        if self._allocator is not None and got.source_node_id != self._allocator:
            return
        msg = got.message
        in_conflict = self.conflict is not None and self.conflict.observe(got, now_ns)
        if isinstance(msg, NodeStatusMsg):
            self.allocator_status.put(msg, now_ns)
        elif isinstance(msg, RawCommandMsg):
            if len(msg.raw) != self.force_map.m:  # before the sequence: it must not move it
                raise MalformedMessage(
                    f"RawCommand: {len(msg.raw)} values for {self.force_map.m} thrusters"
                )
            suspicious = self.conflict is not None and self.conflict.suspicious(now_ns)
            if not self._obey_in_conflict and not self.follower.admit(
                got.transfer_id, msg.raw, self._last_raw, now_ns,
                in_conflict=in_conflict, suspicious=suspicious,
            ):  # fmt: skip
                self.dropped_in_conflict += in_conflict
                if self.follower.take_stop():  # two senders on one sequence: stop now
                    self._apply((0,) * self.force_map.m, now_ns)
                return
            self._apply(msg.raw, now_ns)

    def _apply(self, raw: tuple[int, ...], now_ns: int) -> None:
        command = ThrusterCommand.checked(self.force_map.to_force(raw), self.force_map.m)
        self.raw_commands.put(raw, now_ns)
        if raw != self._last_raw:
            self._last_raw = raw
            self.changes.put(command, now_ns)
        self.commands.put(command, now_ns)

    def _count_malformed(self) -> None:
        self.commands.count_malformed()
