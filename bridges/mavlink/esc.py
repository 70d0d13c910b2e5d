"""The allocator's ESC telemetry as the standard ESC_STATUS / ESC_INFO (four ESCs each).

``ESC_STATUS`` (every call): rpm (int32; unknown -> 0), voltage (V, as esc.Status reports
it; NaN if unknown), current (A; NaN if unknown). ``ESC_INFO`` (at most once per
``period_s``): ``count`` = number of thrusters, ``connection_type`` =
ESC_CONNECTION_TYPE_CAN (4; common.xml's 5 is DShot), ``info`` bit i = ESC i of the
group has reported and is not failed, ``failure_flags`` = ESC_FAILURE_GENERIC (64) for an ESC
the allocator treats as failed (silent past its timeout), ``error_count`` 0 and
``temperature`` INT16_MAX (not reported by uavcan.equipment.esc.Status as we read it).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

ESC_CONNECTION_TYPE_CAN = 4  # common.xml ESC_CONNECTION_TYPE: PPM 0, SERIAL 1, ONESHOT 2,
# I2C 3, CAN 4, DSHOT 5
ESC_FAILURE_GENERIC = 64
INT16_MAX = 32767
_INT32_MAX = 2**31 - 1


@dataclass
class EscInfoClock:
    """When the next ESC_INFO is due, and its packet counter."""

    period_s: float = 1.0
    next_ns: int = 0
    counter: int = 0

    def due(self, now_ns: int) -> bool:
        """True (and the next one scheduled) if an ESC_INFO should go out now."""
        if now_ns < self.next_ns:
            return False
        self.next_ns = now_ns + int(self.period_s * 1e9)
        self.counter = (self.counter + 1) & 0xFFFF
        return True


def _rpm(value: float) -> int:
    if not math.isfinite(value):
        return 0
    return max(-_INT32_MAX, min(_INT32_MAX, round(value)))


def _group(values: Sequence[Any], start: int, fill: Any) -> list[Any]:
    chunk = list(values[start : start + 4])
    return chunk + [fill] * (4 - len(chunk))


def send_standard_esc(
    port: Any,
    rpm: Sequence[float],
    current: Sequence[float],
    age: Sequence[float],
    failed: Sequence[bool],
    n: int,
    clock: EscInfoClock,
    voltage: Sequence[float] = (),
) -> bool:
    """ESC_STATUS for each group of four ESCs, and ESC_INFO when due; True if all went out.
    ``voltage`` (V per ESC, NaN unknown; empty: none known)."""
    stamp = port.time_boot_us()
    info_due = clock.due(time.monotonic_ns())
    ok = True
    for start in range(0, n, 4):
        rpms = [_rpm(float(v)) for v in _group(rpm, start, math.nan)]
        amps = [float(v) for v in _group(current, start, math.nan)]
        volts = [float(v) for v in _group(voltage, start, math.nan)]

        def status(
            mav: Any, s: int = start, r: list[int] = rpms, a: list[float] = amps,
            v: list[float] = volts,
        ) -> None:  # fmt: skip
            mav.esc_status_send(s, stamp, r, v, a)

        ok = port.send(status) and ok
        if info_due:
            ok = _send_info(port, stamp, start, n, age, failed, clock.counter) and ok
    return ok


def _send_info(
    port: Any,
    stamp: int,
    start: int,
    n: int,
    age: Sequence[float],
    failed: Sequence[bool],
    counter: int,
) -> bool:
    ages = _group(age, start, math.inf)
    dead = [bool(f) for f in _group(failed, start, False)]
    online = sum(1 << i for i in range(4) if math.isfinite(ages[i]) and not dead[i])
    flags = [ESC_FAILURE_GENERIC if d else 0 for d in dead]
    fields = (
        start, stamp, counter, n, ESC_CONNECTION_TYPE_CAN, online,
        flags, [0] * 4, [INT16_MAX] * 4,
    )  # fmt: skip
    return bool(port.send(lambda mav: mav.esc_info_send(*fields)))
