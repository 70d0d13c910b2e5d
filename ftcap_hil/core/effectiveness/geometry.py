"""Thruster geometry -> effectiveness matrix B, and the per-cycle command bounds.

A thruster i at body position (x_i, y_i) (m; x forward, y starboard) pushing along the
unit direction a_i = (cos alpha_i, sin alpha_i) with force u_i (N) produces the wrench

    tau_i = u_i * [cos alpha_i,  sin alpha_i,  x_i sin alpha_i - y_i cos alpha_i]^T

so B (3 x m) has those columns. Faults act as tau = B (Delta u + f), eq. (23) of the paper.

In six degrees of freedom (an underwater vehicle; body axes x forward, y starboard, z down,
Fossen's convention) the thruster sits at r_i = (x_i, y_i, z_i) and pushes along
d_i = (cos e_i cos alpha_i, cos e_i sin alpha_i, sin e_i), e_i its elevation (positive
down: a thruster pushing the vehicle up has e = -90 deg). Its column of B (6 x m) is the
force and the moment about the body origin, [d_i; r_i x d_i], for [X, Y, Z, K, M, N]; the
rows X, Y, N of a thruster in the plane (z = 0, e = 0) are exactly its 3-DOF column. The
allocation (``allocator.py``) is the same QP for any number of wrench axes.

The paper's eq. (22) is the special case alpha = pi/4 with four thrusters on a circle of
radius l/2 (``paper_four_thrusters``); the paper never gives l, we default to 0.3 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ftcap_hil.core.messages import FloatArray

WRENCH_AXES = {3: ("X", "Y", "N"), 6: ("X", "Y", "Z", "K", "M", "N")}  # per number of DOF


@dataclass(frozen=True)
class Thruster:
    """One thruster: geometry and limits (SI).

    ``rate_max`` is the largest change of command per second (N/s); ``step_max`` the largest
    change per allocator cycle (N), the paper's form (eq. 2). At most one may be given; if
    both are None the rate is unlimited. ``z_m`` (m, down) and ``elevation_rad`` (the thrust
    line's angle below the horizontal plane) matter only in six degrees of freedom.
    """

    name: str
    x_m: float
    y_m: float
    angle_rad: float
    u_min: float
    u_max: float
    rate_max: float | None = None
    step_max: float | None = None
    z_m: float = 0.0
    elevation_rad: float = 0.0

    def direction(self) -> FloatArray:
        """Unit thrust direction (3,) in body axes (x forward, y starboard, z down)."""
        ce = math.cos(self.elevation_rad)
        a = self.angle_rad
        return np.array([ce * math.cos(a), ce * math.sin(a), math.sin(self.elevation_rad)])

    def column(self) -> FloatArray:
        """This thruster's column of B (3,): [cos a, sin a, x sin a - y cos a] per N (the
        horizontal part of its thrust when it is tilted out of the plane)."""
        c, s = math.cos(self.angle_rad), math.sin(self.angle_rad)
        if self.elevation_rad:
            ce = math.cos(self.elevation_rad)
            c, s = ce * c, ce * s
        return np.array([c, s, self.x_m * s - self.y_m * c])

    def column6(self) -> FloatArray:
        """This thruster's column of B in 6 DOF (6,): [d; r x d] per N (module docstring)."""
        d = self.direction()
        r = np.array([self.x_m, self.y_m, self.z_m])
        return np.concatenate([d, np.cross(r, d)])

    def max_step(self, dt_s: float) -> float:
        """Largest command change allowed in one cycle of length dt_s."""
        if self.step_max is not None:
            return self.step_max
        if self.rate_max is not None:
            return self.rate_max * dt_s
        return math.inf


@dataclass(frozen=True)
class ThrusterSet:
    """The vessel's thrusters in vessel-file order (index i = column i of B); ``dofs``: the
    wrench the vessel is allocated in, 3 (X, Y, N: a surface vessel) or 6 (an underwater
    vehicle)."""

    thrusters: tuple[Thruster, ...]
    dofs: int = 3

    def __post_init__(self) -> None:
        if self.dofs not in WRENCH_AXES:
            raise ValueError(f"ThrusterSet.dofs: 3 or 6, got {self.dofs}")

    @property
    def m(self) -> int:
        """Number of thrusters."""
        return len(self.thrusters)

    @property
    def names(self) -> list[str]:
        """Thruster names, in order."""
        return [t.name for t in self.thrusters]

    @property
    def u_min(self) -> FloatArray:
        """(m,) lower amplitude limits (N)."""
        return np.array([t.u_min for t in self.thrusters])

    @property
    def u_max(self) -> FloatArray:
        """(m,) upper amplitude limits (N)."""
        return np.array([t.u_max for t in self.thrusters])

    def max_step(self, dt_s: float) -> FloatArray:
        """(m,) largest command change per cycle of length ``dt_s`` (N; inf: unlimited)."""
        return np.array([t.max_step(dt_s) for t in self.thrusters])


def effectiveness(thrusters: ThrusterSet, dofs: int | None = None) -> FloatArray:
    """B (3 x m): columns [cos a, sin a, x sin a - y cos a] (N, N, N*m per N of thrust);
    in 6 DOF, B (6 x m) for [X, Y, Z, K, M, N] (module docstring). ``dofs``: the set's own
    unless given (a 6-DOF vehicle's horizontal 3-DOF B, for instance)."""
    dofs = thrusters.dofs if dofs is None else dofs
    if dofs == 3:
        return np.column_stack([t.column() for t in thrusters.thrusters])
    if dofs == 6:
        return np.column_stack([t.column6() for t in thrusters.thrusters])
    raise ValueError(f"effectiveness: dofs is 3 or 6, got {dofs}")


def command_bounds(
    u_min: FloatArray, u_max: FloatArray, max_step: FloatArray, u_prev: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Omega(u_prev) of eq. (2): amplitude limits intersected with the rate box.

    If u_prev lies further than one step outside the amplitude range (limits just
    tightened), the box collapses to the point one step towards the range, so the
    command always moves back at the allowed rate and lo <= hi holds.
    """
    lo = np.maximum(u_min, u_prev - max_step)
    hi = np.minimum(u_max, u_prev + max_step)
    empty = lo > hi
    if True in empty.tolist():  # ndarray.any() costs several times this on (m,)
        toward = np.clip(u_prev, u_min, u_max)
        point = u_prev + np.clip(toward - u_prev, -max_step, max_step)
        lo = np.where(empty, point, lo)
        hi = np.where(empty, point, hi)
    return lo, hi


def paper_four_thrusters(
    l_m: float = 0.3,
    u_limit: float = 0.1,
    step_limit: float | None = 0.09,
    rate_limit: float | None = None,
) -> ThrusterSet:
    """The vessel of section 4.2: eq. (22) with alpha = pi/4.

    Columns of eq. (22): (s, c, -l/2), (s, -c, l/2), (-s, c, l/2), (-s, -c, -l/2), with
    s = sin alpha, c = cos alpha. Each is a thruster at distance l/2 from the centre whose line
    of action passes l/2 from it; the corners (+-l/(2 sqrt 2), +-l/(2 sqrt 2)) realise them.
    """
    h = l_m / (2.0 * math.sqrt(2.0))
    q = math.pi / 4.0
    layout = [("T1", -h, h, q), ("T2", -h, -h, -q), ("T3", h, h, 3 * q), ("T4", h, -h, -3 * q)]
    step = None if rate_limit is not None else step_limit
    return ThrusterSet(
        tuple(
            Thruster(name, x, y, a, -u_limit, u_limit, rate_max=rate_limit, step_max=step)
            for name, x, y, a in layout
        )
    )
