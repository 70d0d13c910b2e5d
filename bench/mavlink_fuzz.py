"""MAVLink fuzz and flood benchmark: the long version of tests/contract/test_mavlink_abuse.py.

One in-process ``MavlinkAllocatorLink`` (the real parameter table, optionally with a signing
key) on loopback; the abuse comes from processes of their own
(``python -m tests.support.mavlink_abuse``); a bare-pymavlink ground station on the link's
configured peer reads a parameter every 50 ms throughout. Phases:

1. ``fuzz``: ``--fuzz`` datagrams (default 10**5) of every abuse kind, a new source port each;
2. ``ports``: ``--ports`` (default 10**4) new source ports sending a ground-station HEARTBEAT;
3. ``flood``: one socket at ``--flood-hz`` (default 10 000) for ``--flood-s`` seconds.

For each phase it reports what was sent, what the kernel dropped at the link's socket, what
the link counted (rate-limited, oversized, parsed, accepted, refused by reason, bad data),
the ping answer ratio, the link's table sizes and the process's RSS change (after the
learnt peers expired). Usage (from the repository root):
``python bench/mavlink_fuzz.py [--fuzz 100000] [--ports 10000] [--flood-hz 10000] [--key]
[--open]``; ``--open`` lifts the per-source budgets so that every fuzzed datagram is parsed
(the parser's robustness, not the rate limits, is then what is measured).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the abuse helpers live with the tests

from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink  # noqa: E402
from bridges.mavlink.allocator_params import allocator_param_specs  # noqa: E402
from bridges.mavlink.config import ALLOCATOR_IDS, MavlinkEndpoint  # noqa: E402
from bridges.mavlink.peers import TrafficLimits  # noqa: E402
from bridges.mavlink.signing import passphrase_to_key, signing_timestamp  # noqa: E402
from ftcap_hil.core.cycle import CoreConfig  # noqa: E402
from tests.support.mavlink_abuse import Pinger, rss_bytes, udp_drops  # noqa: E402
from tests.support.mavlink_peers import RawPeer, free_udp_ports  # noqa: E402

PASSPHRASE = "ftcap-bench"


def _flood(gcs: RawPeer, port: int, rate: float, seconds: float, kind: str, *extra: str) -> int:
    cmd = [sys.executable, "-m", "tests.support.mavlink_abuse", str(port), str(rate)]
    proc = subprocess.Popen(
        [*cmd, str(seconds), kind, *extra], stdout=subprocess.PIPE, text=True, cwd=ROOT
    )
    while proc.poll() is None:
        gcs.pump(0.1)
    out, _ = proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"flooder failed: {kind}")
    return int(out.split()[-1])


def _snapshot(link: MavlinkAllocatorLink) -> dict[str, int]:
    st = link.stats
    table = link._port.table.stats  # noqa: SLF001
    return {
        **{k: int(v) for k, v in vars(st).items()},
        "rate_limited": table.rate_limited,
        "strangers_evicted": table.strangers_evicted,
        "trusted_full": table.trusted_full,
        "peers_full": table.peers_full,
    }


def _phase(
    link: MavlinkAllocatorLink, gcs: RawPeer, port: int, spec: tuple[Any, ...]
) -> dict[str, Any]:
    name, rate, seconds, kind, *extra = spec
    before, kernel0, rss0 = _snapshot(link), udp_drops(port), rss_bytes()
    t0 = time.monotonic()
    gcs.received.clear()
    with Pinger(gcs) as pings:
        sent = _flood(gcs, port, rate, seconds, kind, *extra)
    answered = pings.answered()
    wall = time.monotonic() - t0
    time.sleep(link._port.table.limits.peer_timeout_s + 1.5)  # noqa: SLF001  (let peers expire)
    after = _snapshot(link)
    delta = {k: after[k] - before[k] for k in after if after[k] != before[k]}
    strangers, trusted = link._port.table.sizes()  # noqa: SLF001
    return {
        "phase": name, "sent": sent, "rate_hz": round(sent / wall), "kernel_drops":
        udp_drops(port) - kernel0, "counted": delta, "pings_sent": pings.sent,
        "pings_answered": answered, "answer_ratio": round(answered / max(1, pings.sent), 4),
        "strangers_held": strangers, "trusted_held": trusted, "alive": link.is_alive,
        "rss_change_mib": round((rss_bytes() - rss0) / 2**20, 2),
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Run the three phases and print one JSON line per phase."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fuzz", type=int, default=100_000)
    parser.add_argument("--fuzz-hz", type=float, default=5_000.0)
    parser.add_argument("--ports", type=int, default=10_000)
    parser.add_argument("--ports-hz", type=float, default=1_000.0)
    parser.add_argument("--flood-hz", type=float, default=10_000.0)
    parser.add_argument("--flood-s", type=float, default=10.0)
    parser.add_argument("--key", action="store_true", help="a signing key on both ends")
    parser.add_argument(
        "--open", action="store_true", help="no stranger budget: every datagram is parsed"
    )
    args = parser.parse_args(argv)
    link_port, gcs_port = free_udp_ports(2)
    with tempfile.TemporaryDirectory() as tmp:
        key_file = None
        if args.key:
            key_file = Path(tmp) / "mavlink.key"
            key_file.write_text(PASSPHRASE + "\n")
            key_file.chmod(0o600)
        endpoint = MavlinkEndpoint(
            f"udpin:127.0.0.1:{link_port}", *ALLOCATOR_IDS, (f"127.0.0.1:{gcs_port}",),
            key_file=None if key_file is None else str(key_file),
        )  # fmt: skip
        specs = allocator_param_specs(CoreConfig(), 0.5, 1.0, 0.5, 20.0, 0.1)
        config = AllocatorLinkConfig(4, (1.0, 1.0, 1.0))
        huge = 1e9
        limits = (
            TrafficLimits(
                stranger_rate_hz=huge,
                stranger_burst=huge,
                strangers_rate_hz=huge,
                strangers_burst=huge,
                peer_timeout_s=2.0,
            )  # fmt: skip
            if args.open
            else TrafficLimits(peer_timeout_s=2.0)
        )
        with (
            RawPeer(f"udpin:127.0.0.1:{gcs_port}") as gcs,
            MavlinkAllocatorLink(config, endpoint, specs, limits=limits) as link,
        ):
            if args.key:
                gcs.mav.signing.secret_key = passphrase_to_key(PASSPHRASE)
                gcs.mav.signing.sign_outgoing = True
                gcs.mav.signing.timestamp = signing_timestamp(time.time())
            gcs.wait_for("HEARTBEAT")
            phases = [
                ("fuzz", args.fuzz_hz, args.fuzz / args.fuzz_hz, "fuzz", "--new-ports"),
                ("ports", args.ports_hz, args.ports / args.ports_hz, "heartbeat", "--new-ports"),
                ("flood", args.flood_hz, args.flood_s, "heartbeat"),
            ]
            for spec in phases:
                if spec[1] * spec[2] < 1:
                    continue  # a phase of size 0 is skipped
                result = _phase(link, gcs, link_port, spec)
                result["signing"], result["open"] = bool(args.key), bool(args.open)
                result["params_unchanged"] = link.params.values() == {
                    s.name: float(s.default) for s in specs
                }
                sys.stdout.write(json.dumps(result) + "\n")
                sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
