"""ESC command stream: RawCommand gaps on the bus against issue 13's target.

A ``CanThrusterSink`` with its ESC stream runs in this process while the allocation is
handed in at ``--alloc-hz`` (3.5 Hz: the demo idling); a second hub client in a child
process (its own interpreter, as an ESC would be) stamps every RawCommand it receives. The
hub runs in this process. Reported per stream rate: gap p50 / p99 / max, the share of gaps
over 200 ms (AP_Periph's command timeout) and whether p99 <= 1.5 periods (the target).

Usage: ``python bench/esc_stream.py [--rates 100 200 400] [--seconds 10] [--thrusters 8]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import textwrap
import time

import numpy as np

from bridges.can_io.adapters import CanThrusterSink
from bridges.can_io.bus import open_can_bus
from bridges.can_io.force_map import ForceRawMap
from bridges.can_io.hub import CanHub
from ftcap_hil.runtime.processes import Child

CAPTURE = textwrap.dedent(
    """
    import json, sys, time, can
    bus = can.Bus(interface="canhub", channel=sys.argv[1])
    print("ready", flush=True)
    stamps, end = [], time.monotonic() + float(sys.argv[2])
    while time.monotonic() < end:
        m = bus.recv(0.05)  # first frame of each RawCommand transfer (data type 1030)
        if m is not None and (m.arbitration_id >> 8) & 0xFFFF == 1030 and m.data[-1] & 0x80:
            stamps.append(m.timestamp)
    bus.shutdown()
    print(json.dumps(stamps))
    """
)


def measure(rate_hz: float, seconds: float, m: int, alloc_hz: float) -> dict[str, float]:
    """Gap statistics (ms) of one run at ``rate_hz``."""
    with CanHub(port=0).start() as hub:
        argv = [sys.executable, "-c", CAPTURE, hub.channel, str(seconds + 1.5)]
        proc = Child("capture", argv, stderr="inherit")
        assert proc.next_line(30.0) == "ready"
        with open_can_bus("canhub", hub.channel) as bus:
            sink = CanThrusterSink(bus, ForceRawMap.create([10.0] * m), zero_on_shutdown=False)
            stream = sink.start_stream(rate_hz)
            t0, k = time.monotonic(), 0
            while time.monotonic() < t0 + seconds:
                sink.send(np.full(m, float(k % 10)))
                k += 1
                time.sleep(max(0.0, t0 + k / alloc_hz - time.monotonic()))
            sink.shutdown()
        with proc:
            proc.wait(60.0)
            line = proc.next_line(10.0)
        if line is None:
            raise RuntimeError(f"the capture printed no stamps: {proc.output()[-500:]!r}")
        stamps = json.loads(line)
    gaps = np.diff(np.asarray(stamps[5:-5])) * 1e3  # start-up and shutdown left out
    period = 1e3 / rate_hz
    return {
        "rate_hz": rate_hz,
        "commands": float(len(stamps)),
        "p50_ms": float(np.percentile(gaps, 50)),
        "p99_ms": float(np.percentile(gaps, 99)),
        "max_ms": float(gaps.max()),
        "over_200ms": float(np.mean(gaps > 200.0)),
        "p99_periods": float(np.percentile(gaps, 99) / period),
        "late_ticks": float(stream.late_ticks),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", type=float, nargs="+", default=[100.0, 200.0, 400.0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--thrusters", type=int, default=8)
    ap.add_argument("--alloc-hz", type=float, default=3.5)
    args = ap.parse_args()
    print("rate_Hz  commands  p50_ms  p99_ms  max_ms  >200ms  p99/period  late  target")
    for rate in args.rates:
        r = measure(rate, args.seconds, args.thrusters, args.alloc_hz)
        ok = "met" if r["p99_periods"] <= 1.5 and r["max_ms"] < 200.0 else "MISSED"
        print(
            f"{rate:7.0f}  {r['commands']:8.0f}  {r['p50_ms']:6.2f}  {r['p99_ms']:6.2f}  "
            f"{r['max_ms']:6.1f}  {r['over_200ms']:6.3f}  {r['p99_periods']:10.2f}  "
            f"{r['late_ticks']:4.0f}  {ok}"
        )


if __name__ == "__main__":
    main()
