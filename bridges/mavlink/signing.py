"""MAVLink 2 message signing: the key file and the check of incoming signatures (no I/O
beyond reading the key file).

The key file holds a passphrase on its first line (one word: MAVProxy takes only the first word of
``signing key PASSPHRASE``); the 32-byte secret key is its SHA-256,
the convention of MAVProxy (``signing setup PASSPHRASE``), QGroundControl and Mission
Planner, so the same passphrase configures them. The file must be a regular file owned by
this user and readable by nobody else (mode 0600 or 0400), as ssh demands of its keys.

Incoming frames are checked here rather than by pymavlink's parser, because pymavlink
records a stream's timestamp before it compares the signature: one forged frame with a
far-future timestamp would make every later genuine frame of that stream a "replay", and
forged link ids would grow its stream table without bound. :class:`SignatureVerifier`
checks the signature first and then, per (link id, system, component) stream, that the
timestamp increases, and that a new stream's timestamp is at most a minute old (as the
MAVLink signing specification says), in a bounded table.

Timestamps are in units of 10 us since 2015-01-01 00:00 UTC (the MAVLink definition).
"""

from __future__ import annotations

import hashlib
import hmac
import os
import stat
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

from bridges.mavlink.errors import LinkConfigError

SIGNATURE_LEN = 13  # link id (1) + timestamp (6) + signature (6)
IFLAG_SIGNED = 0x01
_EPOCH_2015_S = 1_420_070_400
_NEW_STREAM_WINDOW = 60 * 100_000  # one minute in 10 us units


def passphrase_to_key(passphrase: str) -> bytes:
    """The 32-byte signing key of a passphrase (SHA-256 of its ASCII bytes)."""
    return hashlib.sha256(passphrase.encode("ascii")).digest()


def load_signing_key(path: str | os.PathLike[str], key: str = "key_file") -> bytes:
    """Read the passphrase in ``path`` and return its key; LinkConfigError naming ``key``
    if the file is missing, not private, or holds no ASCII passphrase."""
    p = Path(path)
    try:
        st = p.lstat()
    except OSError as e:
        raise LinkConfigError(f"{key}: cannot read {str(p)!r}: {e.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        raise LinkConfigError(f"{key}: {str(p)!r} is not a regular file")
    if st.st_uid != os.getuid():
        raise LinkConfigError(f"{key}: {str(p)!r} is owned by uid {st.st_uid}, not by this user")
    if st.st_mode & 0o077:
        mode = stat.S_IMODE(st.st_mode)
        raise LinkConfigError(
            f"{key}: {str(p)!r} has mode {mode:04o}; others must not read it (chmod 600)"
        )
    try:
        line = p.read_text(encoding="ascii").splitlines()[0].strip() if st.st_size else ""
    except (OSError, UnicodeDecodeError) as e:
        raise LinkConfigError(f"{key}: cannot read {str(p)!r}: {e}") from None
    if not line:
        raise LinkConfigError(f"{key}: {str(p)!r} holds no passphrase on its first line")
    return passphrase_to_key(line)


def signing_timestamp(unix_s: float) -> int:
    """MAVLink signing timestamp (10 us units since 2015-01-01) of a UNIX time."""
    return int(max(0.0, unix_s - _EPOCH_2015_S) * 100_000)


def is_signed(msgbuf: bytes | bytearray) -> bool:
    """The frame is MAVLink 2 with the signed flag (and long enough to carry a signature)."""
    return len(msgbuf) > 10 + SIGNATURE_LEN and msgbuf[0] == 0xFD and bool(msgbuf[2] & IFLAG_SIGNED)


@dataclass
class SignatureVerifier:
    """Checks signed frames against ``key`` (module docstring); ``max_streams`` bounds the
    stream table (the least recently seen stream is forgotten first)."""

    key: bytes
    max_streams: int = 256
    _streams: OrderedDict[tuple[int, int, int], int] = field(default_factory=OrderedDict)

    def check(self, msgbuf: bytes | bytearray, system: int, component: int, now: int) -> str:
        """``""`` if the frame's signature is good and fresh, else why not: ``"unsigned"``,
        ``"bad_signature"`` or ``"replay"``. ``now`` is :func:`signing_timestamp` now."""
        if not is_signed(msgbuf):
            return "unsigned"
        expected = hashlib.sha256(self.key + bytes(msgbuf[:-6])).digest()[:6]
        if not hmac.compare_digest(expected, bytes(msgbuf[-6:])):
            return "bad_signature"
        link_id = msgbuf[-SIGNATURE_LEN]
        timestamp = int.from_bytes(msgbuf[-12:-6], "little")
        stream = (link_id, system, component)
        last = self._streams.get(stream)
        if last is not None and timestamp <= last:
            return "replay"
        if last is None and timestamp + _NEW_STREAM_WINDOW < now:
            return "replay"
        self._streams[stream] = timestamp
        self._streams.move_to_end(stream)
        if len(self._streams) > self.max_streams:
            self._streams.popitem(last=False)
        return ""
