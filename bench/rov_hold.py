"""The BlueROV2 Heavy holding station with each thruster dead in turn: the allocation told
(``oracle``) against not told (``cap``), healthy as the reference.

    python bench/rov_hold.py [--vehicle bluerov2-heavy]

One hold per (thruster, mode) at 5 m depth, heading north, in a 0.2 m/s current to the
north, the thruster dying at 30 s once the hold has settled, 30 s more after it
(``ftcap_hil.runtime.rov_hold``); figures after the onset.
Deterministic (no noise, no waves): the table in docs/vessels.md is this command's output.
"""

from __future__ import annotations

import argparse

from ftcap_hil.config.underwater import load_vehicle
from ftcap_hil.runtime.rov_hold import HoldResult, hold


def row(r: HoldResult) -> str:
    return (
        f"| {r.dead or '(none)'} | {r.mode} | {r.depth_dev_max_m * 100:.2f} "
        f"| {r.horizontal_dev_max_m * 100:.1f} | {r.roll_pitch_max_deg:.2f} "
        f"| {r.heading_dev_max_deg:.2f} | {r.unmet_rms:.4f} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--vehicle", default="bluerov2-heavy")
    args = ap.parse_args()
    vehicle = load_vehicle(args.vehicle)
    print(
        "| dead thruster | allocator | depth dev. max (cm) | horizontal dev. max (cm) "
        "| roll/pitch max (deg) | heading dev. max (deg) | unmet wrench RMS (/ scale) |"
    )
    print("|---|---|---|---|---|---|---|")
    print(row(hold(vehicle, "healthy")))
    for i in range(vehicle.thrusters.m):
        for mode in ("oracle", "cap"):
            print(row(hold(vehicle, mode, i)), flush=True)


if __name__ == "__main__":
    main()
