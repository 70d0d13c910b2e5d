"""The realistic truth in the vessel process's shell (sim/live_truth.py, config/sim.py)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from ftcap_hil.config.scenario import SHIPPED
from ftcap_hil.config.sim import load_config
from ftcap_hil.core.faults import Cause
from ftcap_hil.core.messages import FaultInjection, FaultKind
from ftcap_hil.runtime.offline import _advance
from sim.live_truth import SERVO_RPM_FULL, TruthVesselSim, esc_rpm, speed_from_rpm
from sim.truth import TruthModel

SHIPPED_DIR = Path(__file__).resolve().parents[2] / SHIPPED.replace(".", "/")


def scenario_file(tmp_path: Path, onset_s: float) -> Path:
    """cybership2-station with its fault (starboard propeller, delta 0) at ``onset_s``."""
    with open(SHIPPED_DIR / "cybership2-station.toml", "rb") as fh:
        doc = tomllib.load(fh)
    body = (SHIPPED_DIR / "cybership2-station.toml").read_text()
    assert doc["fault"][0]["from"] == 60.0
    path = tmp_path / "cs2.toml"
    path.write_text(body.replace("from = 60.0", f"from = {onset_s!r}"))
    return path


def test_shell_steps_the_offline_truth_exactly(tmp_path: Path) -> None:
    """Commands set at each step's start, steps of the scenario's dt: the shell's truth
    follows the offline loop's stepping (_advance, split at the onset 1.05 s) to 1e-9."""
    cfg = load_config(None, [], str(scenario_file(tmp_path, 1.05)))
    assert cfg.truth is not None and cfg.scenario is not None
    dt = cfg.scenario.dt_s
    sim = TruthVesselSim(cfg.sim, cfg.truth, dt)
    model = TruthModel(cfg.truth, cfg.scenario.x0)
    model.start()
    faults = cfg.scenario.faults
    rng = np.random.default_rng(3)
    u_max = cfg.sim.thrusters.u_max
    odoms = 0
    for k in range(25):
        u = rng.uniform(-0.3, 0.3, cfg.sim.thrusters.m) * u_max
        sim.set_command(u, k * dt)
        sample = sim.step(dt, (k + 1) * dt)
        _advance(model, faults, u, k * dt, dt)
        x = model.x
        x[2] = np.angle(np.exp(1j * x[2]))
        np.testing.assert_allclose(sample.x, x, atol=1e-9)
        odoms += len(sim.odometry(sample, False))
    assert sample.delta[1] == 0.0 and sample.t_s == pytest.approx(2.5)
    assert odoms == 26  # the start's sample and one per 0.1 s step


def test_odometry_and_esc_reports_are_the_truth_s(tmp_path: Path) -> None:
    """Odometry is the sensor's (stamped with the measurement's sim time), esc.Status the
    drives' reports at their 10 Hz; a servo's deflection survives the integer rpm."""
    cfg = load_config(None, [], str(scenario_file(tmp_path, 100.0)))
    assert cfg.truth is not None
    sim = TruthVesselSim(cfg.sim, cfg.truth, 0.02)
    u = 0.5 * cfg.sim.thrusters.u_max
    times, reports = [], []
    for k in range(100):  # 2 s at 50 Hz
        sim.set_command(u, k * 0.02)
        sample = sim.step(0.02, (k + 1) * 0.02)
        times += [o.time_s for o in sim.odometry(sample, True)]
        reports += sim.esc_reports(True) or []
    np.testing.assert_allclose(np.diff(times), 0.1, atol=1e-9)
    assert len(reports) == pytest.approx(20 * cfg.sim.thrusters.m, abs=cfg.sim.thrusters.m)
    props = [r for r in reports if r.index == 0]
    assert props[-1].rpm > 1000.0  # a propeller at half thrust: about 1700 rpm
    assert speed_from_rpm(esc_rpm(0.4321, False), False) == pytest.approx(0.4321, abs=1e-4)
    assert round(esc_rpm(0.4321, False)) / SERVO_RPM_FULL == pytest.approx(0.4321, abs=1e-4)


def test_injections_act_as_causes(tmp_path: Path) -> None:
    """OFF is a dead drive (0 rpm, still reporting), STUCK holds the output, a STUCK value
    is refused, WEAK is a weak motor, OK heals."""
    cfg = load_config(None, [], str(scenario_file(tmp_path, 100.0)))
    assert cfg.truth is not None
    sim = TruthVesselSim(cfg.sim, cfg.truth, 0.02)
    u = 0.5 * cfg.sim.thrusters.u_max
    sim.inject(FaultInjection(0, FaultKind.OFF))
    with pytest.raises(ValueError, match="STUCK takes no value"):
        sim.inject(FaultInjection(1, FaultKind.STUCK, 0.5))
    sim.inject(FaultInjection(2, FaultKind.WEAK, 0.5))
    truth = sim.faults()
    assert truth.causes()[:3] == (Cause.DRIVE_DEAD, Cause.HEALTHY, Cause.WEAK_MOTOR)
    last = {}
    for k in range(100):
        sim.set_command(u, k * 0.02)
        sample = sim.step(0.02, (k + 1) * 0.02)
        sim.odometry(sample, True)
        last.update({r.index: r for r in sim.esc_reports(True) or []})
    assert abs(last[0].rpm) < 1.0 and sim.reporting()[0]
    held = sample.produced[1]
    sim.inject(FaultInjection(1, FaultKind.STUCK))
    for k in range(100, 150):
        sim.set_command(-u, k * 0.02)
        sample = sim.step(0.02, (k + 1) * 0.02)
    assert sim.faults().stuck[1]
    assert sample.delta[1] == 0.0 and sample.f[1] == pytest.approx(held, rel=0.05)
    sim.inject(FaultInjection(0, FaultKind.OK))
    assert sim.faults().causes()[0] is Cause.HEALTHY
