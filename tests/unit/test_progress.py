"""Progress lines of the ground station (``gcs --progress``) and the demo's echo of them."""

from __future__ import annotations

from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest

from ftcap_hil.apps.demo import ProgressTail
from ftcap_hil.core.faults import FaultKind, Injection
from ftcap_hil.core.status import AllocatorStatus, Mode
from ftcap_hil.runtime.gcs_parts import InjectionOutcome, ProgressLine

PHASES = [(0.0, 12.0), (12.0, 45.0), (45.0, 140.0)]


def test_a_line_every_5_s_of_mission_time_whatever_the_cycle() -> None:
    line = ProgressLine(5.0, PHASES, 140.0, write=lambda _: None)
    t = np.arange(0.0, 30.0, 0.2827)  # the paper's T_s: never a multiple of 5 s
    due = [float(x) for x in t if line.due(float(x))]
    assert len(due) == 6  # 0, ~5.1, ~10.2, ~15.3, ~20.1, ~25.2
    assert due[0] == 0.0 and all(0 < b - a <= 5.0 + 0.2827 for a, b in pairwise(due))
    late = ProgressLine(5.0, PHASES, 140.0, write=lambda _: None)
    assert late.due(0.0) and late.due(17.0) and not late.due(19.9) and late.due(20.0)
    with pytest.raises(ValueError, match="every_s"):
        ProgressLine(0.0, PHASES, None)


def test_the_line_says_time_phase_injections_and_verdict() -> None:
    written: list[str] = []
    line = ProgressLine(5.0, PHASES, 140.0, write=written.append)
    x, ref = np.array([0.3, 0.4, 0.0]), np.zeros(3)
    line.show(3.0, x, ref, None, [])
    assert written[-1] == (
        "progress: t 3/140 s; phase 1/3 [0, 12) s; injected: nothing yet; |e| 0.500 m; "
        "allocator: no status yet"
    )
    weak = InjectionOutcome(Injection(12.0, 0, FaultKind.WEAK, 0.9), 12.04, 0.0, "ACCEPTED")
    st = AllocatorStatus(
        mode=Mode.FTCAP, delta_hat=(0.9, 1.0, 0.02, 1.0), faulty=(False, False, True, False)
    )
    line.show(50.0, None, None, st, [weak])
    assert written[-1] == (
        "progress: t 50/140 s; phase 3/3 [45, 140) s; injected: WEAK thruster 1 at 12.0 s "
        "(ACCEPTED); allocator ftcap: flagged 3, delta_hat 0.90 1.00 0.02 1.00"
    )
    told = ProgressLine(5.0, PHASES, None, write=written.append, mode="cap")
    told.show(1.0, None, None, AllocatorStatus(delta_hat=(1.0,), faulty=(False,)), [])
    assert written[-1].endswith("allocator cap: flagged none, delta_hat 1.00")  # not in st


def test_the_demo_echoes_only_complete_progress_lines_once(tmp_path: Path) -> None:
    log = tmp_path / "gcs.log"
    tail = ProgressTail(log)
    assert tail.lines() == []  # no file yet
    log.write_text("INFO connected\nprogress: t 0/30 s; x\nprogress: t 5/3")
    assert tail.lines() == ["progress: t 0/30 s; x"]
    with open(log, "a") as fh:
        fh.write("0 s; y\nWARNING something\n")
    assert tail.lines() == ["progress: t 5/30 s; y"]
    assert tail.lines() == []
    assert ProgressTail(None).lines() == []
