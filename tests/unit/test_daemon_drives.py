"""The allocator told a realistic scenario (config/daemon.py told_by_scenario) and its ESC
telemetry reaching the core's shaft diagnosis (runtime/drive_evidence.py), no processes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ftcap_hil.config.daemon import load_daemon_config
from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.estimation.shaft_types import Hypothesis
from ftcap_hil.core.messages import EscStatus, WrenchSetpoint
from ftcap_hil.core.status import Severity
from ftcap_hil.ports.mailbox import EventQueue, Mailbox
from ftcap_hil.runtime.daemon import AllocatorDaemon, Ports
from ftcap_hil.runtime.offline import run_mode
from sim.live_truth import esc_rpm

S = 1_000_000_000


class Sink:
    def __init__(self) -> None:
        self.commands: list[np.ndarray] = []

    def send(self, u: np.ndarray) -> bool:
        self.commands.append(np.array(u))
        return True

    def send_zero(self) -> bool:
        return True

    def tick(self, now_ns: int | None = None) -> None:
        return None

    def take_lapse(self) -> bool:
        return False


class Texts:
    def __init__(self) -> None:
        self.got: list[str] = []

    def publish(self, status: object) -> None:
        return None

    def announce(self, text: str, severity: Severity) -> None:
        self.got.append(text)


def test_the_allocator_is_told_what_the_offline_core_is_told() -> None:
    cfg = load_daemon_config(None, [], "cybership2-station")
    sc = load_scenario("cybership2-station")
    d = cfg.daemon
    assert d.thrusters.m == 5 and d.drives is not None and len(d.drives) == 5
    np.testing.assert_array_equal(d.B, sc.B)  # the mismatched geometry (rudder 5 deg off)
    assert d.rate_hz == pytest.approx(10.0) and d.estimation_period_s == pytest.approx(0.1)
    assert d.core.estimator == sc.core.estimator  # sensor noise, sea-state model
    assert d.core.thruster_lag_s == sc.core.thruster_lag_s and d.core.diagnosis == sc.core.diagnosis
    assert cfg.ports.can.esc_node_ids is None or len(cfg.ports.can.esc_node_ids) == 5
    kept = load_daemon_config(None, ["daemon.rate_hz=20"], "cybership2-station").daemon
    assert kept.rate_hz == 20.0
    with pytest.raises(ConfigError, match="not a realistic scenario"):
        load_daemon_config(None, [], "paper-4.2-ex1")


def _daemon() -> tuple[AllocatorDaemon, Mailbox[WrenchSetpoint], EventQueue[EscStatus], Texts]:
    cfg = load_daemon_config(None, [], "cybership2-station").daemon
    sp: Mailbox[WrenchSetpoint] = Mailbox("setpoint")
    reports: EventQueue[EscStatus] = EventQueue("esc")
    boxes = [Mailbox[EscStatus](f"esc{i}", history=reports) for i in range(5)]
    texts = Texts()
    ports = Ports(
        [sp], [Mailbox("odometry")], Sink(), [texts],
        esc_ages=lambda now: np.array([b.age_s(now) for b in boxes]),
        esc_latest=lambda: [None if (s := b.latest()) is None else s.value for b in boxes],
        esc_reports=reports,
    )  # fmt: skip
    daemon = AllocatorDaemon(cfg, ports)
    daemon.test_boxes = boxes  # type: ignore[attr-defined]
    return daemon, sp, reports, texts


def test_esc_status_reaches_the_shaft_diagnosis_and_silence_is_not_a_dead_thruster() -> None:
    """Every esc.Status goes to the core (a dead starboard drive found from its 0 rpm under
    command); with no telemetry the core runs on the motion, says so, and allocates every
    thruster (a silent ESC is telemetry lost, not a failed thruster)."""
    daemon, sp, _, texts = _daemon()
    boxes: list[Mailbox[EscStatus]] = daemon.test_boxes  # type: ignore[attr-defined]
    assert daemon.drive.diagnosing and daemon.core.shaft is not None
    tau = np.array([2.0, 0.0, 0.0])  # ahead: both propellers commanded
    now = 10 * S
    speeds = np.zeros(len(boxes))  # each drive's speed, lagging its command as a drive does
    for k in range(40):  # 4 s at 10 Hz, the statuses of the commands in force
        now = 10 * S + k * S // 10
        sp.put(WrenchSetpoint(tau), now)
        u = daemon.core.u_prev
        for i, box in enumerate(boxes):
            drive = daemon.config.drives[i]  # type: ignore[index]
            if drive.is_shaft:
                ref = np.sign(u[i]) * np.sqrt(abs(u[i]) / drive.k_thrust)
                speeds[i] += min(0.1 / drive.time_constant_s, 1.0) * (ref - speeds[i])
                n = speeds[i]
                rpm = 0.0 if i == 1 else esc_rpm(n, True)  # starboard: 0 rpm
                amps = drive.idle_a + (abs(u[i]) * abs(n) * 0.3 if i != 1 else 0.0)
            else:
                rpm, amps = esc_rpm(u[i] / drive.full_force_n, False), 0.1
            box.put(EscStatus(i, round(rpm), amps, 12.0), now)
        result = daemon.cycle(now)
    assert daemon.drive.received == 40 * 5
    assert result is not None and result.shaft is not None
    assert result.shaft.fresh.all()
    assert result.faulty[1] and result.shaft.hypothesis[1] is Hypothesis.DRIVE_DEAD
    assert not result.faulty[[0, 2, 3, 4]].any()
    assert not any("motion alone" in t for t in texts.got)
    for _ in range(10):  # the ESCs go silent: telemetry lost, the motion judges
        now += S // 10
        sp.put(WrenchSetpoint(tau), now)
        result = daemon.cycle(now)
    assert result is not None and result.shaft is not None and not result.shaft.fresh.any()
    assert any("thrusters judged by the motion alone" in t for t in texts.got)
    assert result.u[0] != 0.0  # the port propeller still allocated: silent is not dead


def test_offline_core_and_daemon_core_are_one_code_path() -> None:
    """The daemon's core is built as the offline loop's (drives, lag, estimator): the same
    first command for the same demand."""
    sc = load_scenario("cybership2-station")
    rec = run_mode(replace(sc, duration_s=0.2), sc.core.mode)
    daemon, sp, _, _ = _daemon()
    tau = np.array([rec.columns[f"v_dem_{i}"][0] for i in (1, 2, 3)])
    sp.put(WrenchSetpoint(tau), 5 * S)
    result = daemon.cycle(5 * S)
    assert result is not None
    offline_u = np.array([rec.columns[f"u_{i}"][0] for i in range(1, 6)])
    np.testing.assert_allclose(result.u, offline_u, atol=1e-9)
