"""Which RawCommands an ESC obeys when anyone may send with the allocator's node ID.

DroneCAN has no authentication, so the genuine sender is the stream being followed:

* a RawCommand is obeyed only if its transfer ID continues the last one taken (+1, or +2
  past one lost frame); any other is dropped (``off_sequence``);
* the stream is picked up again from any frame after ``resync_s`` without one in sequence
  (an allocator restart resets its transfer IDs), but never while a node-ID conflict is
  on: then the ESCs' command timeout stops the thrusters rather than let a stranger take
  the stream over;
* while the ID is suspicious (an anomaly within the conflict detector's window) a changed
  command is applied only once the next frame in sequence repeats it: the allocator's
  stream repeats every command at its rate, while a stranger's frame whose transfer ID
  happened to fit is followed by a genuine frame with the genuine command (``unconfirmed``
  counts changes never repeated);
* two different commands with one transfer ID while the ID is suspicious are two senders
  on one sequence (``collisions``): zero at once (:meth:`take_stop`), then nothing is
  obeyed until the suspicion is over.

Before the first anomaly a stranger's first frame is obeyed if its transfer ID happens to
fit (2 in 32), until the genuine frame with that ID arrives (one stream period, 10 ms at
100 Hz) and stops the thrusters. A stranger that reads the bus and sends the next transfer
IDs first still gets through: no rule on an unauthenticated bus stops that
(docs/security.md).
"""

from __future__ import annotations


class CommandFollower:
    """The module docstring's rules; called from the receive thread only."""

    def __init__(self, resync_s: float = 0.05) -> None:
        self.resync_ns = int(resync_s * 1e9)
        self.off_sequence = 0
        self.unconfirmed = 0
        self.collisions = 0
        self._stop = False
        self._tid: tuple[int, int, tuple[int, ...]] | None = None  # (ID, stamp, raw) taken
        self._pending: tuple[int, ...] | None = None  # a changed command awaiting its repeat
        self._collided = False

    def admit(
        self,
        transfer_id: int,
        raw: tuple[int, ...],
        applied: tuple[int, ...] | None,
        now_ns: int,
        *,
        in_conflict: bool,
        suspicious: bool,
    ) -> bool:
        """True to obey ``raw`` (with ``transfer_id``, received at ``now_ns``); ``applied``
        is the command in force."""
        last = self._tid
        step = None if last is None else (transfer_id - last[0]) & 0x1F
        if not suspicious:
            self._collided = False
        elif last is not None and step == 0 and raw != last[2]:
            self._stop = self._stop or not self._collided
            self._collided = True
            self.collisions += 1
            self._pending = None
        lapsed = last is None or now_ns - last[1] > self.resync_ns
        if self._collided or (step not in (1, 2) and (in_conflict or not lapsed)):
            self.off_sequence += 1
            return False
        self._tid = (transfer_id, now_ns, raw)
        if not suspicious or raw == applied or raw == self._pending:
            self._pending = None
            return True
        if self._pending is not None:
            self.unconfirmed += 1
        self._pending = raw
        return False

    def take_stop(self) -> bool:
        """True once after two senders were found on one sequence: command zero now."""
        stop, self._stop = self._stop, False
        return stop
