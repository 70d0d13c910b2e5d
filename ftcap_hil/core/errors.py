"""The project's exception tree and the exit codes every command shares.

Every exception ftcap-hil raises on purpose derives from :class:`FtcapError` (as qpsolvers'
``QPError`` or python-can's ``CanError``), and each kind carries the exit code a command
ends with when it reaches the command line unhandled:

=====  ===============  =============================================================
code   name             meaning
=====  ===============  =============================================================
0      OK               done
1      FAILURE          a port, a peer process or a run failed after a valid start
2      CONFIG           bad command line or configuration (names the file, table, key)
3      NO_ANSWER        a peer (vessel, allocator) did not answer at start-up
4      LINK_LOST        a peer went silent mid-run
5      REFUSED          a request (fault injection, parameter) was refused or unanswered
130    INTERRUPTED      stopped by SIGINT / SIGTERM before finishing its job
=====  ===============  =============================================================

Per-cycle numerical outcomes (a failed solve, a stale port) are data, never exceptions.
"""

from __future__ import annotations

import enum


class ExitCode(enum.IntEnum):
    """Process exit codes of every ``ftcap-hil`` command (module docstring)."""

    OK = 0
    FAILURE = 1
    CONFIG = 2
    NO_ANSWER = 3
    LINK_LOST = 4
    REFUSED = 5
    INTERRUPTED = 130


class FtcapError(Exception):
    """Root of the project's exceptions; ``exit_code`` is what a command returns for it."""

    exit_code: ExitCode = ExitCode.FAILURE


class ConfigError(FtcapError, ValueError):
    """A configuration value is wrong; the message names the file, the table, the key and
    the value (and, for an unknown key, the nearest valid one)."""

    exit_code = ExitCode.CONFIG


class MalformedMessage(FtcapError, ValueError):
    """Input from a port that must be counted and dropped (raised by decoders)."""


class PortError(FtcapError, RuntimeError):
    """A port (a bus, a socket, a session) cannot be opened or has failed."""


def require_member(key: str, value: object, cls: type[enum.Enum]) -> None:
    """ValueError naming ``key`` and the values of ``cls`` unless ``value`` is one of its
    members: a switch of the core is its enum, never the enum's spelling in a file (the
    config reader converts)."""
    if not isinstance(value, cls):
        names = ", ".join(repr(m.value) for m in cls)
        raise ValueError(f"{key}: expected {cls.__name__} ({names}), got {value!r}")
