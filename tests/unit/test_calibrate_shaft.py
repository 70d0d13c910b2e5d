"""The drives' calibration (bench/calibrate_shaft.py) reproduces: the seed goes into the
scenario before it draws its truth, so one seed gives the same thresholds twice and another
seed gives others. Shortened (one current, 40 s) to keep the unit tier quick; the committed
values come from the documented full command."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

from ftcap_hil.core.estimation.shaft import ResidualSample

BENCH = Path(__file__).resolve().parents[2] / "bench" / "calibrate_shaft.py"


@pytest.fixture(scope="module")
def calibration() -> ModuleType:
    spec = importlib.util.spec_from_file_location("ftcap_calibrate_shaft", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclass looks itself up by module name
    spec.loader.exec_module(module)
    return module


def shortened(module: ModuleType, seed: int) -> dict[str, float]:
    return dict(module.calibrate(
        "cybership2", [seed], 40.0, campaign="sweeps", workers=1, labels=["cs2-current-0.50"],
    ))  # fmt: skip


def test_one_seed_twice_gives_the_same_values_and_another_seed_others(
    calibration: ModuleType,
) -> None:
    first, again, other = (shortened(calibration, s) for s in (1001, 1001, 1002))
    assert first == again
    assert first["runs"] == 1 and first["hours"] == pytest.approx(40.0 / 3600.0)
    keys = [k for k in calibration.KEYS if k in first]
    assert {"band_rel", "band_res", "cusum_h", "load_h"} <= set(keys)
    assert {k: first[k] for k in keys} != {k: other.get(k) for k in keys}
    assert all(first[k] >= 0.0 for k in keys) and first["band_res"] > 0.0
    assert first["cusum_h"] >= 8.0 and first["load_h"] >= 8.0


def test_the_seeds_default_to_the_campaigns_tuning_seeds(calibration: ModuleType) -> None:
    todo = calibration.flights("sweeps", ["supply"], None, 60.0)
    assert {f.seed for f in todo} == {1001, 1002, 1003}
    assert {f.label for f in todo} == {f"supply-bf{b}" for b in range(2, 7)}
    assert {f.doc["scenario"]["seed"] for f in todo} == {1001, 1002, 1003}
    assert all(f.doc["scenario"]["duration"] == 60.0 for f in todo)


def _samples(
    index: int, load_a: float = 50.0, error_a: float = 0.0, lowest: float = 1.0
) -> list[ResidualSample]:
    """300 healthy-looking samples of thruster ``index`` at 1-10 rev/s: the load about
    ``load_a`` (A), +-2 A of noise about ``error_a``, the amplitude's ratio 1-1.1 but for
    one sample at ``lowest``."""
    return [
        ResidualSample(index, 0.5 * k, 1.0 + (k % 30) * 0.3, 0.004 * (-1) ** k,
                       load_a * (1.0 + (k % 7) / 7.0), error_a + 2.0 * (-1) ** k,
                       ratio=lowest if k == 150 else 1.0 + 0.05 * (k % 3))
        for k in range(300)
    ]  # fmt: skip


def test_the_load_threshold_rests_on_the_samples_the_load_test_takes(
    calibration: ModuleType,
) -> None:
    """A shaft near standstill draws its in-flow's share and the sensor's noise, not a
    load: a steady +8 A there (at 1-2 A of load) feeds no load test, so it sets no
    threshold; the same +8 A where the speed draws 100 A does."""
    healthy = _samples(0, 100.0) + _samples(1, 1.0)
    low = calibration.fit([healthy + _samples(2, 1.0, 8.0)], 1.0 / 60.0)
    high = calibration.fit([healthy + _samples(2, 100.0, 8.0)], 1.0 / 60.0)
    assert low["load_h"] == 8.0 and low["load_peak"] < 5.0
    assert high["load_h"] > 100.0


def test_the_amplitude_loss_is_the_largest_a_healthy_amplitude_showed(
    calibration: ModuleType,
) -> None:
    """``amplitude_loss``: how far healthy amplitudes dipped (the weak gate without the speed
    test sits at twice that); nothing else moves with it."""
    dipped = calibration.fit([_samples(0, lowest=0.95) + _samples(1, lowest=0.8)], 1.0 / 60.0)
    steady = calibration.fit([_samples(0, lowest=0.95) + _samples(1, lowest=0.97)], 1.0 / 60.0)
    assert dipped["amplitude_loss"] == pytest.approx(0.2)
    assert steady["amplitude_loss"] == pytest.approx(0.05)
    others = [k for k in calibration.KEYS if k != "amplitude_loss" and k in dipped]
    assert {k: dipped[k] for k in others} == {k: steady[k] for k in others}


def test_the_check_names_every_key_the_preset_holds_otherwise(calibration: ModuleType) -> None:
    """``--check`` (CI): a fit equal to the file passes; one that moved names the key."""
    from ftcap_hil.config.presets import load_preset

    committed = load_preset("supply").diagnosis
    fitted = {k: float(committed[k]) for k in calibration.KEYS if k in committed}
    assert calibration.differences("supply", fitted) == []
    moved = dict(fitted, load_h=fitted["load_h"] + 1.0)
    (line,) = calibration.differences("supply", moved)
    assert "supply: [diagnosis] load_h" in line
