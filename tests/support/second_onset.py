"""The claims about example 1's second onset in a live flight, judged on what the flight left:
the allocator's log and the ground station's timeseries.csv (``tests/docker/test_compose.py``
flies the compressed example 1 to 75 s through the Compose topology and judges it here).

At 45 s thruster 1 drops to delta 0.8, thruster 3 goes dead with a 0.01 N bias, and the turn
to [2, 2, pi] saturates every thruster. Healthy thrusters 2 and 4 must never be flagged. They
were (delta_hat 0.27 and 0.65 for 10-25 s) while the simulated vessel applied each command
from the start of the sim step in which it arrived, up to 20 ms before the allocator sent it:
the allocator's command averages then mismatched the vessel's motion by ~2 % of full scale at
every large command change, and the few samples of the restarted window believed it. And for
one cycle (CI, twice) while the allocator's estimator samples depended on the phase of its
deadlines against the vessel's steps; they now lie on the vessel's grid.
"""

from __future__ import annotations

ONSET_S = 45.0


def check_second_onset(allocator_log: str, rows: list[dict[str, float]]) -> float:
    """Assert the module docstring's claims; the time (s) from the onset to thruster 3 found
    dead."""
    flagged = [ln for ln in allocator_log.splitlines() if "fault detected" in ln]
    warned = [ln for ln in allocator_log.splitlines() if "WARNING" in ln]  # the why
    assert not [ln for ln in flagged if "thruster 2 " in ln or "thruster 4 " in ln], warned
    assert any("thruster 3 fault detected" in ln for ln in flagged), flagged
    # When thruster 3 is found dead depends on which way the vessel turns to psi = pi (the
    # sign of its heading error at 45 s, noise): one way its command saturates at -0.1 and
    # delta_hat_3 reaches 0 within ~2 s; the other way it saturates at +0.1, delta_3 u_3 + f_3
    # cannot be told from a bias while the command is constant, and it is found when the
    # command leaves saturation, 11-14 s after the onset (measured). Either way: once
    # delta_hat_3 is under the 0.1 dead threshold it stays there (not pinned near 0: one CI
    # run measured 0.06-0.09 after a large command change) and thruster 3 gets nothing but
    # recovery probes (0.01 N); the healthy ones stay above the flag level.
    after_onset = [r for r in rows if r["t"] > ONSET_S]
    t_dead = next((r["t"] for r in after_onset if r["delta_hat_3"] < 0.1), None)
    assert t_dead is not None, [round(r["delta_hat_3"], 2) for r in after_onset]
    after = [r for r in after_onset if r["t"] > t_dead + 0.6]  # the next cycle has it out
    assert after and all(r["delta_hat_3"] < 0.1 for r in after), [r["delta_hat_3"] for r in after]
    assert all(abs(r["u_3"]) <= 0.0101 for r in after), [r["u_3"] for r in after]
    healthy = [(r["delta_hat_2"], r["delta_hat_4"]) for r in after_onset if r["t"] > 50.0]
    assert all(min(pair) > 0.85 for pair in healthy), healthy
    return t_dead - ONSET_S
