"""The truth of a realistic scenario (:mod:`ftcap_hil.config.realistic`): the preset in the
scenario's ``[conditions]``, its stated ``[environment]`` and ``[sensor]``, departing from
its data sheets by the seed's draw of ``[uncertainty]`` (:mod:`ftcap_hil.config.uncertainty`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ftcap_hil.config.presets import VesselPreset
from ftcap_hil.config.tables import Table
from ftcap_hil.config.uncertainty import Drawn
from sim.environment import EnvironmentConfig
from sim.sensors import SensorConfig
from sim.thrusters import DEFAULT_PROPELLER, ThrusterBankConfig
from sim.truth import TruthConfig


def truth_of(
    preset: VesselPreset,
    root: Table,
    seed: int,
    substeps: int,
    dt_s: float,
    stated: EnvironmentConfig,
    drawn: Drawn | None,
) -> tuple[TruthConfig, SensorConfig | None]:
    """The truth: the preset in the scenario's conditions and stated environment, departing
    from its data sheets by ``drawn`` (None: as stated)."""
    cond = root.table("conditions")
    env_on = cond.boolean("environment", True)
    sensors_on = cond.boolean("sensors", True)
    lag_on = cond.boolean("thruster_lag", True)
    quant_on = cond.boolean("quantization", True)
    telemetry_on = cond.boolean("drive_telemetry", True)
    reverse = cond.number("reverse_gain", 1.0, positive=True)
    deadband = cond.number("deadband_rel", 0.0, lo=0.0, hi=0.5)
    cond.finish()
    ths = preset.thrusters
    u_abs = np.maximum(np.abs(ths.u_min), np.abs(ths.u_max))
    seeds = np.random.SeedSequence(seed).spawn(3)
    drives, feedback = preset.drives, None
    gain = np.ones(ths.m) if drawn is None else drawn.thrust_gain
    lag = preset.time_constants_s * (1.0 if drawn is None else drawn.lag_factor)
    bank = ThrusterBankConfig.create(
        ths.m,
        time_constant_s=lag.tolist() if lag_on else 0.0,
        forward_gain=gain.tolist(),
        reverse_gain=(reverse * gain).tolist(),
        deadband_n=(deadband * u_abs).tolist(),
        u_max_abs=u_abs.tolist() if quant_on else None,
        actuator=drives.actuators if drives is not None else DEFAULT_PROPELLER,
        full_force_n=u_abs.tolist(),
        seed=int(seeds[2].generate_state(1)[0]),
    )
    if drives is not None and telemetry_on:
        feedback = dataclasses.replace(drives.feedback, seed=int(seeds[2].generate_state(2)[1]))
    sensor = _sensor(preset, root.table("sensor"), int(seeds[1].generate_state(1)[0]), dt_s, drawn)
    env = dataclasses.replace(_drawn_sea(stated, drawn), seed=int(seeds[0].generate_state(1)[0]))
    truth = TruthConfig(
        vessel=preset.vessel,
        B=preset.B,
        bank=bank,
        hull=preset.hull,
        environment=env if env_on else None,
        sensor=sensor if sensors_on else None,
        substeps=substeps,
        seed=int(seeds[0].generate_state(1)[0]),
        feedback=feedback,
    )
    return truth, truth.sensor


def _drawn_sea(stated: EnvironmentConfig, drawn: Drawn | None) -> EnvironmentConfig:
    """The true sea: the stated Hs and Tp times this seed's factors."""
    if drawn is None:
        return stated
    w = stated.waves
    waves = dataclasses.replace(w, hs_m=w.hs_m * drawn.hs_factor, tp_s=w.tp_s * drawn.tp_factor)
    return dataclasses.replace(stated, waves=waves)


def sheet_noise(preset: VesselPreset) -> np.ndarray:
    """(6,) the sensor's data-sheet noise std per axis of x."""
    s = preset.sensors
    return np.array(
        [s.position_std_m, s.position_std_m, s.heading_std_rad,
         s.velocity_std_m_s, s.velocity_std_m_s, s.yaw_rate_std_rad_s]
    )  # fmt: skip


def _sensor(
    preset: VesselPreset, t: Table, seed: int, dt_s: float, drawn: Drawn | None = None
) -> SensorConfig:
    """The true sensor: the data sheet's noise and the ``[sensor]`` table's departures,
    plus this seed's draw (noise factor per axis, bias, delay and dropouts added)."""
    noise = sheet_noise(preset) * (1.0 if drawn is None else drawn.noise_factor)
    bias_rel = t.number("bias_rel", 0.0, lo=0.0)
    bias_tau = t.number("bias_tau_s", 60.0, positive=True)
    delay = t.number("delay_s", 0.0, lo=0.0)
    dropout = t.number("dropout_p", 0.0, lo=0.0, hi=1.0)
    t.finish()
    if drawn is not None:
        bias_rel += drawn.sensor_bias_rel
        delay += drawn.delay_s
        dropout = min(1.0, dropout + drawn.dropout_p)
    return SensorConfig(
        noise_std=noise,
        bias_std=bias_rel * noise,
        bias_tau_s=np.full(6, bias_tau),
        rate_hz=1.0 / dt_s,
        delay_s=delay,
        dropout_p=dropout,
        seed=seed,
    )
