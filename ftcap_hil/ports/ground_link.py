"""What a ground station's link offers the ground-station driver, in the project's types.

:class:`GroundLink` is the port the driver (:mod:`ftcap_hil.runtime.ground_station`) is
handed, as a python-can module is handed a ``BusABC``: the vessel's odometry and the
allocator's status and commands in mailboxes, heartbeats waited for, wrenches and fault
injections sent, the fault-injection switch and the allocator's mode set and read back.
:class:`bridges.mavlink.gcs.MavlinkGcsLink` is one; the protocol's own numbers (FTC_MODE
codes, MAV_RESULT, parameter types) stay in its bridge.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from ftcap_hil.core.messages import FaultKind, Odometry, ThrusterCommand
from ftcap_hil.core.status import AllocatorStatus, Mode
from ftcap_hil.ports.mailbox import Mailbox, Stamped

Ids = tuple[int, int]  # (system, component) of a peer


@dataclass(frozen=True)
class StatusText:
    """One text a peer sent (chunks reassembled): who sent it, its syslog severity level as
    sent (0 emergency .. 7 debug) and the text."""

    system: int
    component: int
    severity: int
    text: str


@dataclass(frozen=True)
class ParamWrite:
    """One parameter set and its answer: the name and value asked for, and the value the
    peer reports back (None: it did not answer)."""

    name: str
    value: int
    reported: float | None


class Reply(Protocol):
    """A peer's answer to a command; its ``name`` is ``"ACCEPTED"`` when it was carried out."""

    @property
    def name(self) -> str: ...


class GroundLink(Protocol):
    """The ground station's link to the vessel and the allocator (module docstring).

    The blocking calls wait at most their ``timeout_s``; they are for the ground-station
    driver's start-up and its injector thread, never for its control loop.
    """

    @property
    def vessel_ids(self) -> Ids: ...
    @property
    def allocator_ids(self) -> Ids: ...
    @property
    def odometry(self) -> Mailbox[Odometry]: ...
    @property
    def allocator_status(self) -> Mailbox[AllocatorStatus]: ...
    @property
    def thruster_commands(self) -> Mailbox[ThrusterCommand]: ...

    def wait_heartbeat(self, ids: Ids, timeout_s: float = ...) -> bool:
        """True once a heartbeat of the peer ``ids`` was heard (False after ``timeout_s``)."""
        ...

    def wait_ready(self, ids: Ids, timeout_s: float = ...) -> bool:
        """True once the peer ``ids`` reports itself past its start-up (its loop runs)."""
        ...

    def allow_fault_injection(self, *, timeout_s: float = ...) -> ParamWrite:
        """Switch the vessel's fault injection on; the write and its answer."""
        ...

    def release_vessel(self, *, timeout_s: float = ...) -> ParamWrite:
        """Start a simulated vessel held at sim time 0; the write and its answer."""
        ...

    def request_mode(self, mode: Mode, *, timeout_s: float = ...) -> ParamWrite:
        """Ask the allocator to run in ``mode``; the write and its answer."""
        ...

    def read_mode(self, *, timeout_s: float = ...) -> Mode | None:
        """The allocator's mode as it reports it (None: no report within ``timeout_s``)."""
        ...

    def send_wrench(self, tau: Sequence[float], target: Ids | None = None) -> bool:
        """One wrench setpoint [X (N), Y (N), N (N*m)], body frame; False if not sent."""
        ...

    def inject_failure(
        self,
        kind: FaultKind,
        thruster: int | None,
        value: float = math.nan,
        *,
        timeout_s: float = ...,
        attempts: int = ...,
    ) -> Reply | None:
        """A fault of ``kind`` on the vessel's ``thruster`` (0-based; None: all); its reply,
        None if none came after ``attempts`` tries of ``timeout_s`` each."""
        ...

    def drain_statustexts(self) -> list[Stamped[StatusText]]:
        """Every text received since the last drain, oldest first."""
        ...
