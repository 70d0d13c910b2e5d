"""The MAVLink command protocol for one component: every command gets a COMMAND_ACK.

:class:`CommandService` answers ``COMMAND_LONG`` and ``COMMAND_INT`` addressed to its
component: a command it has a handler for gets the handler's MAV_RESULT; any other command
addressed to this component gets ``MAV_RESULT_UNSUPPORTED``; one from a system that is not
authorized gets ``MAV_RESULT_DENIED``. Broadcasts (target component 0) are answered only
when handled, so that one broadcast does not draw an ACK storm from every component.

Built in, on every component:

* ``MAV_CMD_REQUEST_MESSAGE`` (512) for ``AUTOPILOT_VERSION`` (148) or ``HEARTBEAT`` (0),
  and the older ``MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES`` (520): ACCEPTED, then the
  message. Other message ids: UNSUPPORTED.
* ``AUTOPILOT_VERSION`` says MAVLink 2 and byte-wise parameter encoding
  (``MAV_PROTOCOL_CAPABILITY_MAVLINK2 | MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE``), the
  project's version as ``flight_sw_version`` (major << 24 | minor << 16 | patch << 8 | 255,
  255 = release) and a ``uid`` derived from the system and component ids.
"""

from __future__ import annotations

import enum
import importlib.metadata
import re
from collections.abc import Callable, Mapping
from typing import Any

from bridges.mavlink.link import MavlinkPort, Route

MAV_CMD_REQUEST_MESSAGE = 512
MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES = 520
MSG_ID_HEARTBEAT = 0
MSG_ID_AUTOPILOT_VERSION = 148


class MavResult(enum.IntEnum):
    """MAV_RESULT, as carried by COMMAND_ACK."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4


CommandHandler = Callable[[Any], MavResult]
"""Called on the dispatch thread with the COMMAND_LONG / COMMAND_INT; returns the result."""


def software_version() -> int:
    """The installed ftcap-hil version packed as AUTOPILOT_VERSION.flight_sw_version."""
    try:
        text = importlib.metadata.version("ftcap-hil")
    except importlib.metadata.PackageNotFoundError:
        return 0
    parts = [int(p) for p in re.findall(r"\d+", text)[:3]] + [0, 0, 0]
    major, minor, patch = (min(p, 255) for p in parts[:3])
    return major << 24 | minor << 16 | patch << 8 | 255


class CommandService:
    """COMMAND_LONG / COMMAND_INT for the component of ``port`` (module docstring)."""

    def __init__(self, handlers: Mapping[int, CommandHandler] | None = None) -> None:
        self._handlers: dict[int, CommandHandler] = {
            MAV_CMD_REQUEST_MESSAGE: self._request_message,
            MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: self._request_capabilities,
            **(handlers or {}),
        }
        self._port: MavlinkPort | None = None
        self._after_ack: Callable[[], object] | None = None
        self.acked = 0  # COMMAND_ACKs sent (any result)

    def routes(self) -> dict[str, Route]:
        """The command handlers for a :class:`MavlinkPort`'s route table."""
        return {"COMMAND_LONG": Route(self._on_command), "COMMAND_INT": Route(self._on_command)}

    def attach(self, port: MavlinkPort) -> None:
        """The port that answers go out on (before it, commands are ignored)."""
        self._port = port

    def _on_command(self, msg: Any, now_ns: int) -> None:
        port = self._port
        if port is None or not port.accepts(msg.target_system, msg.target_component):
            return
        handler = self._handlers.get(msg.command)
        if msg.target_component == 0 and handler is None:
            return  # a broadcast we do not handle is not ours to refuse
        self._after_ack = None
        if not port.authorized(msg):
            result = MavResult.DENIED
        elif handler is None:
            result = MavResult.UNSUPPORTED
        else:
            result = handler(msg)
        self._ack(msg, result)
        if self._after_ack is not None:
            self._after_ack()

    def _ack(self, msg: Any, result: MavResult) -> None:
        assert self._port is not None
        command, src = msg.command, (msg.get_srcSystem(), msg.get_srcComponent())
        sent = self._port.reply(
            lambda mav: mav.command_ack_send(command, int(result), 0, 0, src[0], src[1])
        )
        self.acked += int(sent)

    # --- built-in commands ---

    def _request_message(self, msg: Any) -> MavResult:
        wanted = msg.param1
        if wanted == MSG_ID_AUTOPILOT_VERSION:
            self._after_ack = self.send_autopilot_version
        elif wanted == MSG_ID_HEARTBEAT:
            assert self._port is not None
            self._after_ack = self._port.send_heartbeat
        else:
            return MavResult.UNSUPPORTED
        return MavResult.ACCEPTED

    def _request_capabilities(self, msg: Any) -> MavResult:
        if msg.param1 != 1:
            return MavResult.DENIED
        self._after_ack = self.send_autopilot_version
        return MavResult.ACCEPTED

    def send_autopilot_version(self) -> None:
        """AUTOPILOT_VERSION for this component (module docstring)."""
        port = self._port
        assert port is not None
        d = port.dialect
        capabilities = d.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        capabilities |= d.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
        version = software_version()
        uid = 0x4654_4341_5000_0000 | port.system_id << 8 | port.component_id  # "FTCAP" ids
        zeros = [0] * 8
        port.reply(
            lambda mav: mav.autopilot_version_send(
                capabilities, version, 0, 0, 0, zeros, zeros, zeros, 0, 0, uid
            )
        )
