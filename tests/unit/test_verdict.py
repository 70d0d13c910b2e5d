"""The demo's verdict: a fault phase is handled when every estimate converged within 0.1 of
the truth and the HIL tracking is within 2x + 5 cm of the offline F-TCAP run's."""

from __future__ import annotations

from typing import Any

from ftcap_hil.report.summary import verdict_lines


def _phase(start: float, end: float, trk: float, conv: list[Any], err: list[float]) -> dict:
    return {"start": start, "end": end, "tracking_rms": trk,
            "delta_convergence_time": conv, "delta_error_final": err}  # fmt: skip


def _flight(trk: float, conv: list[Any], err: list[float]) -> dict:
    inj = [{"at_s": 12.0, "sent_at_s": 12.1, "thruster": 1, "kind": "WEAK", "value": 0.5,
            "result": "ACCEPTED"}]  # fmt: skip
    phases = [_phase(0, 12, 0.01, [0.0] * 4, [0.0] * 4), _phase(12, 40, trk, conv, err)]
    return {"phases": [[0, 12], [12, 40]], "modes": {"ftcap": {"phases": phases,
            "injections": inj}}}  # fmt: skip


OFFLINE = {
    "modes": {
        m: {"phases": [_phase(0, 12, 0.01, [], []), _phase(12, 40, trk, [], [])]}
        for m, trk in (("none", 0.0), ("cap", 0.9), ("ftcap", 0.1))
    }
}


def test_a_converged_estimate_and_close_tracking_is_handled() -> None:
    lines, ok = verdict_lines(_flight(0.12, [0.7, 0.0, 0.0, 0.0], [0.02, 0, 0, 0]), OFFLINE)
    assert ok and lines[-1] == "VERDICT: every fault phase handled", lines
    assert "WEAK thruster 1 (0.5)" in lines[2] and "after 0.7 s" in lines[2], lines
    assert "offline F-TCAP 0.100, CAP 0.900" in lines[2], lines


def test_an_estimate_that_never_converges_is_not_handled() -> None:
    lines, ok = verdict_lines(_flight(0.12, [None, 0.0, 0.0, 0.0], [0.5, 0, 0, 0]), OFFLINE)
    assert not ok and "never within 0.1 for thruster [1]" in lines[2], lines
    assert lines[-1].startswith("VERDICT: not every fault handled"), lines


def test_tracking_far_worse_than_offline_is_not_handled() -> None:
    lines, ok = verdict_lines(_flight(0.5, [0.7, 0.0, 0.0, 0.0], [0.02, 0, 0, 0]), OFFLINE)
    assert not ok and "NOT handled" in lines[2], lines
