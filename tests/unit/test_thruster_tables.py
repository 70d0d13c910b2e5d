"""One reader of ``[[thruster]]`` tables (config/vessel.py ``thruster_from``): a vessel
table's ``[[vessel.thruster]]`` and a vessel preset's ``[[thruster]]`` follow the same
rules, so what one accepts or refuses the other does too."""

from __future__ import annotations

import math
import re
from importlib import resources
from pathlib import Path

import pytest

from ftcap_hil.config.presets import load_preset
from ftcap_hil.config.vessel import thrusters_from_table
from ftcap_hil.core.errors import ConfigError

SUPPLY = resources.files("ftcap_hil.data.vessels").joinpath("supply.toml").read_text()
FIRST = (
    'name = "bow_tunnel_1"\nx = 30.0\ny = 0.0\nangle_deg = 90.0\n'
    "u_min = -200000.0               # -3.2 x 250^2 N\nu_max = 200000.0\n"
)

BOW = {"x": 30.0, "y": 0.0, "u_min": -2.0, "u_max": 2.0}


def _vessel_table(entry: dict[str, object]) -> dict[str, object]:
    return {"thruster": [entry, {"name": "aft", "x": -1.0, "y": 0.0, "angle_deg": 0.0,
                                 "u_min": -1.0, "u_max": 1.0}]}  # fmt: skip


def _preset(tmp_path: Path, first_entry: str | dict[str, object]) -> Path:
    """supply.toml with its first thruster's entry (all but its lag) replaced."""
    if isinstance(first_entry, dict):
        first_entry = "".join(f"{k} = {v!r}\n".replace("'", '"') for k, v in first_entry.items())
    assert FIRST in SUPPLY
    path = tmp_path / "supply.toml"
    path.write_text(SUPPLY.replace(FIRST, first_entry, 1))
    return path


def test_direction_reads_as_the_angle_in_both() -> None:
    ths = thrusters_from_table(_vessel_table({"name": "bow", **BOW, "direction": [0.0, 2.0]}))
    assert ths.thrusters[0].angle_rad == math.pi / 2


def test_a_preset_thruster_may_give_a_direction(tmp_path: Path) -> None:
    path = _preset(tmp_path, {"name": "bow_tunnel_1", **BOW, "direction": [0.0, 1.0]})
    preset = load_preset(path)
    assert preset.thrusters.thrusters[0].angle_rad == math.pi / 2
    assert preset.thrusters.thrusters[0].x_m == 30.0


def test_an_unnamed_thruster_is_named_by_its_position_in_both(tmp_path: Path) -> None:
    ths = thrusters_from_table(_vessel_table({**BOW, "angle_deg": 90.0}))
    assert ths.names[0] == "T1"
    preset = load_preset(_preset(tmp_path, {**BOW, "angle_deg": 90.0}))
    assert preset.thrusters.names[0] == "T1"


RULES = [
    ({"rate_max": 1.0, "step_max": 0.1}, "give rate_max or step_max, not both"),
    ({"u_min": 1.0}, "need u_min <= 0 <= u_max, got 1.0, 2.0"),
    ({"direction": [0.0, 1.0]}, "give angle_deg (and elevation_deg) or direction, not both"),
    ({"rate_max": -1.0}, "rate_max: expected a finite number > 0, got -1.0"),
]


@pytest.mark.parametrize(("extra", "message"), RULES)
def test_the_same_rules_refuse_the_same_entry(
    tmp_path: Path, extra: dict[str, object], message: str
) -> None:
    entry = {"name": "bow", **BOW, "angle_deg": 90.0, **extra}
    with pytest.raises(ConfigError, match=re.escape(message)) as in_vessel:
        thrusters_from_table(_vessel_table(entry))
    assert "[[vessel.thruster]][0]" in str(in_vessel.value)
    path = _preset(tmp_path, entry)
    with pytest.raises(ConfigError, match=re.escape(message)) as in_preset:
        load_preset(path)
    assert f"{path}: [[thruster]][0]" in str(in_preset.value)


def test_duplicate_names_are_refused_in_both(tmp_path: Path) -> None:
    entry = {"name": "aft", **BOW, "angle_deg": 90.0}
    with pytest.raises(ConfigError, match="duplicate names in"):
        thrusters_from_table(_vessel_table(entry))
    with pytest.raises(ConfigError, match="thruster: duplicate names in"):
        load_preset(_preset(tmp_path, FIRST.replace("bow_tunnel_1", "bow_tunnel_2")))


def test_a_preset_thruster_also_needs_its_lag(tmp_path: Path) -> None:
    text = SUPPLY.replace("time_constant_s = 1.0\n", "", 1)
    path = tmp_path / "supply.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"\[\[thruster\]\]\[0\] time_constant_s: missing"):
        load_preset(path)
