"""Named vessels of the unit tests (no tests here): the paper's eq. (22) as literal matrices, a
six- and an eight-thruster layout read through the product's vessel-table parser."""

from __future__ import annotations

import tomllib

import numpy as np

from ftcap_hil.config.vessel import thrusters_from_table
from ftcap_hil.core.effectiveness.geometry import ThrusterSet

S = 0.7071067811865476  # sin(pi/4) = cos(pi/4)

# Eq. (22) with alpha = pi/4, written out literally.
EQ22_L03 = np.array(
    [
        [S, S, -S, -S],
        [S, -S, S, -S],
        [-0.15, 0.15, 0.15, -0.15],
    ]
)
EQ22_L05 = np.array(
    [
        [S, S, -S, -S],
        [S, -S, S, -S],
        [-0.25, 0.25, 0.25, -0.25],
    ]
)

# Six thrusters: two stern mains at (-1, -+0.5) pointing forward, two bow tunnels pushing to
# starboard, two diagonal thrusters at +-45 deg on the beam.
SIX_THRUSTER_TOML = """
[vessel]
[[vessel.thruster]]
name = "stern_port"
x = -1.0
y = -0.5
angle_deg = 0.0
u_min = -2.0
u_max = 4.0
step_max = 0.5
[[vessel.thruster]]
name = "stern_stbd"
x = -1.0
y = 0.5
angle_deg = 0.0
u_min = -2.0
u_max = 4.0
step_max = 0.5
[[vessel.thruster]]
name = "bow_tunnel_fwd"
x = 1.2
y = 0.0
angle_deg = 90.0
u_min = -1.0
u_max = 1.0
rate_max = 2.0
[[vessel.thruster]]
name = "bow_tunnel_aft"
x = 0.8
y = 0.0
angle_deg = 90.0
u_min = -1.0
u_max = 1.0
rate_max = 2.0
[[vessel.thruster]]
name = "diag_port"
x = 0.0
y = -0.6
angle_deg = 45.0
u_min = -1.5
u_max = 1.5
[[vessel.thruster]]
name = "diag_stbd"
x = 0.0
y = 0.6
angle_deg = -45.0
u_min = -1.5
u_max = 1.5
step_max = 0.3
"""

# Eight thrusters, some given by direction vectors.
EIGHT_THRUSTER_TOML = """
[vessel]
thruster = [
  { name = "A1", x = -2.0, y = -1.0, angle_deg = 0.0, u_min = -5.0, u_max = 10.0, rate_max = 5.0 },
  { name = "A2", x = -2.0, y = 1.0, angle_deg = 0.0, u_min = -5.0, u_max = 10.0, rate_max = 5.0 },
  { name = "T1", x = 2.0, y = 0.0, angle_deg = 90.0, u_min = -3.0, u_max = 3.0 },
  { name = "T2", x = -1.5, y = 0.0, angle_deg = 90.0, u_min = -3.0, u_max = 3.0 },
  { name = "C1", x = 1.0, y = 1.0, direction = [1.0, 1.0], u_min = -2.0, u_max = 2.0 },
  { name = "C2", x = 1.0, y = -1.0, direction = [1.0, -1.0], u_min = -2.0, u_max = 2.0 },
  { name = "D1", x = 2.0, y = -1.0, direction = [0.0, -1.0], u_min = 0.0, u_max = 2.0 },
  { name = "D2", x = -1.0, y = 0.5, direction = [-3.0, 4.0], u_min = -1.0, u_max = 0.0 },
]
"""


def six_thrusters() -> ThrusterSet:
    return thrusters_from_table(tomllib.loads(SIX_THRUSTER_TOML)["vessel"])


def eight_thrusters() -> ThrusterSet:
    return thrusters_from_table(tomllib.loads(EIGHT_THRUSTER_TOML)["vessel"])
