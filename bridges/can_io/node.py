"""DroneCAN node services: GetNodeInfo and param.GetSet answered, node-ID conflicts
detected, node health.

``CanNodeServer`` serves one or more node IDs on a bus (the allocator's node; on the vessel
side, each simulated ESC's): it answers ``uavcan.protocol.GetNodeInfo`` requests addressed to
them (name, software version, unique ID, the node's current NodeStatus), which is how the
DroneCAN GUI tool, ``dronecan``'s ``NodeMonitor`` and autopilots list a bus, and
``uavcan.protocol.param.GetSet`` for the nodes given parameters (:class:`NodeParam`), as an
AP_Periph node does: by index (0, 1, ... until an empty answer: how the GUI tool lists
them) or by name, each answer with the value, default, bounds and name. A request to set a
read-only parameter, or with a value of another type or out of bounds, changes nothing and
is answered with the value as it is (the protocol's "the actual value after the update").
Requests longer than a frame are reassembled with ``dronecan``'s own transport codec; a
malformed one (bad CRC, toggle, unknown type) is counted (``bad_requests``) and dropped.

Node-ID conflicts. DroneCAN has no authentication: any node may send with any source ID, so
a second node claiming ours (misconfigured or hostile) can only be detected, not prevented.

* The owner of an ID (``CanNodeServer``) sees its own frames only if someone else sent them
  (neither the hub nor SocketCAN echoes a socket's own frames): any message from one of its
  IDs is a conflict.
* A listener (the vessel's ``CanCommandSource``) sees two senders on one ID as a broken
  sequence (:class:`ConflictDetector`): transfer IDs that do not step by one, NodeStatus
  uptimes that go back and then forward again. Several anomalies close together are a
  conflict; a single one (a lost frame, the node restarting) is not.

Either way the conflict is counted (``conflicts``: times one started; ``conflict_frames``
or ``anomalies``), logged on its start and end (a warning, then an info after
``clear_after_s`` without evidence), and readable as ``in_conflict``.

Health: :func:`health_for` maps an :class:`AllocatorStatus` to NodeStatus health (table in
its docstring), :func:`mode_for` to the NodeStatus mode; the daemon passes both to
``CanThrusterSink.set_status``.
"""

from __future__ import annotations

import hashlib
import logging
import math
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import can
import dronecan
from dronecan.transport import Frame, Transfer, TransferManager

from bridges.can_io.codec import (
    PRIORITY_LOWEST,
    DataType,
    EscStatusMsg,
    FrameId,
    Health,
    Mode,
    NodeStatusMsg,
    RawCommandMsg,
    Received,
    check_node_id,
)
from ftcap_hil.core.effectiveness.geometry import Thruster
from ftcap_hil.core.status import AllocatorStatus

log = logging.getLogger(__name__)

GET_NODE_INFO = dronecan.uavcan.protocol.GetNodeInfo
GET_NODE_INFO_ID = GET_NODE_INFO.default_dtid  # 1
GET_SET = dronecan.uavcan.protocol.param.GetSet
GET_SET_ID = GET_SET.default_dtid  # 11

ParamValue = bool | int | float | str
_MAX_PARTIAL = 32  # unfinished multi-frame requests kept at once (a GetSet by name: 1-16 frames)


@dataclass
class NodeParam:
    """One parameter a node serves over param.GetSet: ``name`` (<= 92 ASCII characters),
    its ``value`` (bool, int, float or str: the protocol's boolean, integer, real or string
    value), its ``default`` (the value if None), optional numeric bounds, and whether a
    GetSet may change it. Mutable: the server updates ``value`` on an accepted set."""

    name: str
    value: ParamValue
    default: ParamValue | None = None
    minimum: float | None = None
    maximum: float | None = None
    writable: bool = False

    def __post_init__(self) -> None:
        if not self.name or len(self.name) > 92 or not self.name.isascii():
            raise ValueError(f"param name: 1..92 ASCII characters, got {self.name!r}")
        if self.default is None:
            self.default = self.value

    def accepts(self, value: ParamValue) -> bool:
        """Whether a set to ``value`` is allowed (writable, same type, within bounds)."""
        if not self.writable or type(value) is not type(self.value):
            return False
        if isinstance(value, bool | str):
            return True
        if not math.isfinite(value):
            return False  # never a NaN or an infinity into a parameter
        low = self.minimum is None or value >= self.minimum
        return low and (self.maximum is None or value <= self.maximum)


def _put_value(field: object, value: ParamValue | None, numeric: bool = False) -> None:
    """Set a param.Value (or NumericValue with ``numeric``) union to ``value`` (None: empty)."""
    if value is None:
        return
    if isinstance(value, bool):
        if not numeric:
            field.boolean_value = int(value)  # type: ignore[attr-defined]
    elif isinstance(value, int):
        field.integer_value = value  # type: ignore[attr-defined]
    elif isinstance(value, float):
        field.real_value = value  # type: ignore[attr-defined]
    elif not numeric:
        field.string_value = value  # type: ignore[attr-defined]


def _get_value(field: object) -> ParamValue | None:
    """A received param.Value union as a Python value (None: empty)."""
    tag = dronecan.get_active_union_field(field)
    if tag == "integer_value":
        return int(field.integer_value)  # type: ignore[attr-defined]
    if tag == "real_value":
        return float(field.real_value)  # type: ignore[attr-defined]
    if tag == "boolean_value":
        return bool(field.boolean_value)  # type: ignore[attr-defined]
    if tag == "string_value":
        return bytes(field.string_value).decode("ascii", "replace")  # type: ignore[attr-defined]
    return None


def get_set_response(param: NodeParam | None) -> object:
    """The GetSet response for ``param`` (None: the empty answer that ends a listing)."""
    response = GET_SET.Response()
    if param is None:
        return response
    _put_value(response.value, param.value)
    _put_value(response.default_value, param.default)
    _put_value(response.max_value, param.maximum, numeric=True)
    _put_value(response.min_value, param.minimum, numeric=True)
    response.name = param.name
    return response


@dataclass(frozen=True)
class NodeInfo:
    """What GetNodeInfo tells about a node: ``name`` (<= 80 ASCII characters, reverse-DNS
    style), software version, hardware version and a 16-byte ``unique_id``."""

    name: str
    software_major: int = 0
    software_minor: int = 1
    vcs_commit: int = 0
    unique_id: bytes = bytes(16)
    hardware_major: int = 0
    hardware_minor: int = 0

    def __post_init__(self) -> None:
        if not self.name or len(self.name) > 80 or not self.name.isascii():
            raise ValueError(f"node name: 1..80 ASCII characters, got {self.name!r}")
        if len(self.unique_id) != 16:
            raise ValueError(f"unique_id: 16 bytes, got {len(self.unique_id)}")
        for key in ("software_major", "software_minor", "hardware_major", "hardware_minor"):
            if not 0 <= getattr(self, key) <= 255:
                raise ValueError(f"{key}: 0..255, got {getattr(self, key)}")


def unique_id_for(name: str, node_id: int) -> bytes:
    """A stable 16-byte unique ID for a simulated or software node (no hardware to read
    one from): the name and node ID, hashed."""
    return hashlib.blake2b(f"{name}#{node_id}".encode(), digest_size=16).digest()


def node_info_response_frames(
    info: NodeInfo, status: NodeStatusMsg, *, source_node_id: int, dest_node_id: int,
    transfer_id: int, priority: int = PRIORITY_LOWEST,
) -> list[tuple[int, bytes]]:  # fmt: skip
    """(CAN ID, data) of the frames of one GetNodeInfo response, in bus order."""
    response = GET_NODE_INFO.Response()
    s = response.status
    s.uptime_sec, s.health, s.mode = status.uptime_s, int(status.health), int(status.mode)
    s.sub_mode, s.vendor_specific_status_code = status.sub_mode, status.vendor_status
    sw = response.software_version
    sw.major, sw.minor = info.software_major, info.software_minor
    sw.optional_field_flags, sw.vcs_commit = 1, info.vcs_commit  # vcs_commit is set
    hw = response.hardware_version
    hw.major, hw.minor = info.hardware_major, info.hardware_minor
    hw.unique_id = list(info.unique_id)
    response.name = info.name
    return service_response_frames(
        response, source_node_id=source_node_id, dest_node_id=dest_node_id,
        transfer_id=transfer_id, priority=priority,
    )  # fmt: skip


def service_response_frames(
    response: object, *, source_node_id: int, dest_node_id: int, transfer_id: int,
    priority: int = PRIORITY_LOWEST,
) -> list[tuple[int, bytes]]:  # fmt: skip
    """(CAN ID, data) of the frames of one service ``response`` (a dronecan Response), in
    bus order."""
    transfer = Transfer(
        transfer_id=transfer_id & 0x1F,
        source_node_id=check_node_id("source_node_id", source_node_id),
        dest_node_id=check_node_id("dest_node_id", dest_node_id),
        payload=response,
        transfer_priority=priority,
        request_not_response=False,
        service_not_message=True,
    )
    return [(f.message_id, bytes(f.bytes)) for f in transfer.to_frames()]


@dataclass(frozen=True)
class ServiceRequest:
    """A service request to a served node, as received (its transfer reassembled)."""

    service_id: int
    source_node_id: int
    dest_node_id: int
    transfer_id: int
    priority: int


class Conflict:
    """Start/end bookkeeping of one node ID's conflict (module docstring)."""

    def __init__(self, what: str, clear_after_s: float) -> None:
        self.what = what
        self._clear_ns = int(clear_after_s * 1e9)
        self._last_ns: int | None = None
        self.conflicts = 0

    def evidence(self, now_ns: int, detail: str) -> None:
        """Record evidence now; starts a conflict (warning) if none is on."""
        if not self.active(now_ns):
            self.conflicts += 1
            log.warning("%s: node-ID conflict: %s", self.what, detail)
        self._last_ns = now_ns

    def active(self, now_ns: int | None = None) -> bool:
        """Evidence seen within ``clear_after_s``; logs the end once it is over."""
        if self._last_ns is None:
            return False
        now = time.monotonic_ns() if now_ns is None else now_ns
        if now - self._last_ns <= self._clear_ns:
            return True
        self._last_ns = None
        log.info("%s: node-ID conflict over", self.what)
        return False


class ConflictDetector:
    """A listener's view of one remote node ID (module docstring): transfer IDs per data
    type must step by one, the NodeStatus uptime must not go back and forward again;
    ``threshold`` anomalies within ``window_s`` are a conflict."""

    def __init__(
        self, node_id: int, *, threshold: int = 4, window_s: float = 2.0,
        clear_after_s: float = 3.0,
    ) -> None:  # fmt: skip
        self.node_id = check_node_id("node_id", node_id)
        self._threshold, self._window_ns = threshold, int(window_s * 1e9)
        self._last_tid: dict[int, int] = {}
        self._uptime: int | None = None
        self._went_back = False
        self._recent: deque[int] = deque(maxlen=threshold)
        self._conflict = Conflict(f"node {node_id}", clear_after_s)
        self.anomalies = 0
        self._last_anomaly_ns: int | None = None

    @property
    def conflicts(self) -> int:
        """Conflicts started so far."""
        return self._conflict.conflicts

    def in_conflict(self, now_ns: int | None = None) -> bool:
        """A conflict is on now."""
        return self._conflict.active(now_ns)

    def suspicious(self, now_ns: int) -> bool:
        """A conflict is on, or an anomaly was seen within the window: a second sender may
        be on the ID (its next frames must prove themselves)."""
        last = self._last_anomaly_ns
        recent = last is not None and now_ns - last <= self._window_ns
        return recent or self.in_conflict(now_ns)

    def observe(self, got: Received, now_ns: int) -> bool:
        """Take one transfer from ``node_id``; True while a conflict is on."""
        kind = _data_type_of(got)
        last = self._last_tid.get(kind)
        self._last_tid[kind] = got.transfer_id
        if last is not None and got.transfer_id != (last + 1) & 0x1F:
            self._anomaly(now_ns, f"transfer ID {last} -> {got.transfer_id}")
        if isinstance(got.message, NodeStatusMsg):
            self._uptime_step(got.message.uptime_s, now_ns)
        return self.in_conflict(now_ns)

    def _uptime_step(self, uptime_s: int, now_ns: int) -> None:
        prev, self._uptime = self._uptime, uptime_s
        if prev is None:
            return
        if uptime_s + 1 < prev:
            self._went_back = True  # a restart, or a second node: wait and see
        elif self._went_back and uptime_s > prev + 2:
            self._went_back = False
            self._anomaly(now_ns, f"uptime back and forth ({prev} -> {uptime_s} s)", weight=2)

    def _anomaly(self, now_ns: int, detail: str, weight: int = 1) -> None:
        self.anomalies += 1
        self._last_anomaly_ns = now_ns
        for _ in range(weight):
            self._recent.append(now_ns)
        if len(self._recent) == self._threshold and now_ns - self._recent[0] <= self._window_ns:
            self._conflict.evidence(now_ns, f"two senders on node {self.node_id}: {detail}")


def _data_type_of(got: Received) -> int:
    if isinstance(got.message, RawCommandMsg):
        return int(DataType.RAW_COMMAND)
    if isinstance(got.message, EscStatusMsg):
        return int(DataType.ESC_STATUS)
    return int(DataType.NODE_STATUS)


class CanNodeServer(can.Listener):
    """Answers GetNodeInfo for ``nodes`` (and param.GetSet for those in ``params``) and flags
    others sending as them (module docstring).

    ``status(node_id)`` gives the NodeStatus to report in a response (the node's current
    health, mode and uptime). Joins ``notifier`` (python-can allows one per bus: pass the
    one of the bus's other receiver) or starts its own. Sends with ``send_timeout_s``.
    """

    def __init__(
        self,
        bus: can.BusABC,
        nodes: Mapping[int, NodeInfo],
        status: Callable[[int], NodeStatusMsg],
        *,
        notifier: can.Notifier | None = None,
        clear_after_s: float = 3.0,
        send_timeout_s: float = 0.01,
        params: Mapping[int, Sequence[NodeParam]] | None = None,
    ) -> None:
        self.bus = bus
        self.nodes = {check_node_id("nodes", n): info for n, info in nodes.items()}
        self.params = {n: list(ps) for n, ps in (params or {}).items()}
        unknown = sorted(set(self.params) - set(self.nodes))
        if unknown:
            raise ValueError(f"params for nodes not served: {unknown}")
        for n, ps in self.params.items():
            names = [p.name for p in ps]
            if len(set(names)) != len(names):
                raise ValueError(f"node {n}: duplicate parameter names in {names}")
        self._transfers = TransferManager()
        self.bad_requests = 0
        self.params_answered = 0
        self.sets_refused = 0
        self._status = status
        self._send_timeout_s = send_timeout_s
        self._conflicts = {n: Conflict(f"node {n}", clear_after_s) for n in self.nodes}
        self.requests_answered = 0
        self.send_errors = 0
        self.conflict_frames = 0
        self._closed = False
        self._own_notifier = notifier is None
        self._notifier = notifier if notifier is not None else can.Notifier(bus, [], 0.1)
        self._notifier.add_listener(self)

    @property
    def conflicts(self) -> int:
        """Conflicts started so far, over all served node IDs."""
        return sum(c.conflicts for c in self._conflicts.values())

    def in_conflict(self, node_id: int | None = None, now_ns: int | None = None) -> bool:
        """A conflict is on now for ``node_id`` (None: any served ID)."""
        ids: Iterable[int] = self._conflicts if node_id is None else (node_id,)
        return any(self._conflicts[n].active(now_ns) for n in ids)

    def on_message_received(self, msg: can.Message) -> None:
        """python-can callback (Notifier thread): answer requests, watch for our IDs."""
        if self._closed or not msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
            return
        can_id, data = msg.arbitration_id, bytes(msg.data)
        if can_id & 0x8080 == 0x8080:  # a service request: ours if addressed to a served ID
            if (can_id >> 8) & 0x7F in self.nodes and data:
                self._request_frame(can_id, data)
            return
        fid = FrameId.parse(can_id)
        if fid is not None and fid.source_node_id in self.nodes:
            self.conflict_frames += 1
            self._conflicts[fid.source_node_id].evidence(
                time.monotonic_ns(), f"a frame 0x{can_id:08X} from our own ID"
            )

    def _request_frame(self, can_id: int, data: bytes) -> None:
        """One frame of a request to us: a complete transfer is decoded and answered."""
        frames = self._transfers.receive_frame(Frame(can_id, data))
        active = self._transfers.active_transfers
        while len(active) > _MAX_PARTIAL:  # a flood of unfinished transfers: oldest out
            oldest = next(iter(active))
            del active[oldest], self._transfers.active_transfer_timestamps[oldest]
            self.bad_requests += 1
        if frames is None:
            return
        transfer = Transfer()
        try:
            transfer.from_frames(frames)
        # any decoder error: an exception here would end the python-can Notifier's thread
        except Exception as e:  # noqa: BLE001
            self.bad_requests += 1
            log.debug("malformed service request 0x%08X dropped: %s", can_id, e)
            return
        request = ServiceRequest(
            transfer.data_type_id, transfer.source_node_id, transfer.dest_node_id,
            transfer.transfer_id, transfer.transfer_priority,
        )  # fmt: skip
        if request.service_id == GET_NODE_INFO_ID:
            self._answer(request)
        elif request.service_id == GET_SET_ID:  # a node without parameters: the empty list
            self._answer_param(request, transfer.payload)

    def _answer_param(self, request: ServiceRequest, payload: object) -> None:
        params = self.params.get(request.dest_node_id, [])
        name = bytes(payload.name).decode("ascii", "replace")  # type: ignore[attr-defined]
        if name:
            param = next((p for p in params if p.name == name), None)
        else:
            index = int(payload.index)  # type: ignore[attr-defined]
            param = params[index] if index < len(params) else None
        value = _get_value(payload.value)  # type: ignore[attr-defined]
        if param is not None and value is not None:
            if param.accepts(value):
                param.value = value
            else:
                self.sets_refused += 1
                log.debug("node %d: set %s = %r refused", request.dest_node_id, param.name, value)
        frames = service_response_frames(
            get_set_response(param), source_node_id=request.dest_node_id,
            dest_node_id=request.source_node_id, transfer_id=request.transfer_id,
            priority=request.priority,
        )  # fmt: skip
        if self._send(frames, request.dest_node_id, "param.GetSet"):
            self.params_answered += 1

    def _send(self, frames: list[tuple[int, bytes]], node: int, what: str) -> bool:
        try:
            for can_id, data in frames:
                self.bus.send(
                    can.Message(arbitration_id=can_id, data=data, is_extended_id=True),
                    timeout=self._send_timeout_s,
                )
        except (can.CanError, OSError) as e:
            self.send_errors += 1
            log.debug("%s response from node %d failed: %s", what, node, e)
            return False
        return True

    def _answer(self, request: ServiceRequest) -> None:
        node = request.dest_node_id
        frames = node_info_response_frames(
            self.nodes[node], self._status(node), source_node_id=node,
            dest_node_id=request.source_node_id, transfer_id=request.transfer_id,
            priority=request.priority,
        )  # fmt: skip
        if self._send(frames, node, "GetNodeInfo"):
            self.requests_answered += 1

    def stop(self) -> None:
        """Called by the Notifier when it stops."""

    def shutdown(self) -> None:
        """Stop answering (and the Notifier, if this server started it). Idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._own_notifier:
            self._notifier.stop()
        else:
            self._notifier.remove_listener(self)

    def __enter__(self) -> CanNodeServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()


def sim_esc_node(index: int, node_id: int, thruster: Thruster) -> tuple[NodeInfo, list[NodeParam]]:
    """What a simulated ESC node tells the bus about itself: its GetNodeInfo (name
    ``org.ftcap.sim.esc<index>``, a unique ID from it) and its parameters, read-only (the
    simulator's ESCs are configured by the vessel file, not over the bus): ``CAN_NODE``,
    ``ESC_INDEX`` (the RawCommand slot it follows), ``ESC_BIDIR`` (1: negative commands
    reverse it, as an AP_Periph ESC set bidirectional; 0: they are clamped) and the thrust
    range it maps commands to, ``THR_MAX_N`` and ``THR_MIN_N`` (N)."""
    name = f"org.ftcap.sim.esc{index}"
    info = NodeInfo(name, 0, 1, 0, unique_id_for(name, node_id))
    params = [
        NodeParam("CAN_NODE", node_id, minimum=1, maximum=127),
        NodeParam("ESC_INDEX", index, minimum=0, maximum=19),
        NodeParam("ESC_BIDIR", int(thruster.u_min < 0.0), minimum=0, maximum=1),
        NodeParam("THR_MAX_N", float(thruster.u_max)),
        NodeParam("THR_MIN_N", float(thruster.u_min)),
    ]
    return info, params


def health_for(status: AllocatorStatus) -> Health:
    """NodeStatus health of the allocator's node for its latest status.

    =========  ==========================================================================
    health     when
    =========  ==========================================================================
    ERROR      the allocation is degraded (the QP failed, the clipped fallback was used),
               an ESC is silent (``esc_failed``), or every thruster is flagged
    WARNING    a thruster is flagged faulty or being probed, the setpoint or telemetry
               is stale, or estimation is frozen
    OK         otherwise
    =========  ==========================================================================
    """
    flagged = status.flagged
    if status.degraded or any(status.esc_failed) or (flagged and all(flagged)):
        return Health.ERROR
    if (
        any(status.faulty)
        or any(status.probing)
        or status.setpoint_stale
        or status.telemetry_stale
        or status.estimation_frozen
    ):
        return Health.WARNING
    return Health.OK


def mode_for(status: AllocatorStatus) -> Mode:
    """NodeStatus mode: INITIALIZATION until the first cycle ran, then OPERATIONAL."""
    return Mode.INITIALIZATION if status.cycle == 0 else Mode.OPERATIONAL
