"""Realistic scenarios: a relative ``[plant] preset`` path is read from the folder of the file
that names it (scenario or campaign file), wherever the command runs; ``[environment]`` sets
the environment's levels over the preset's, strictly, from a scenario or a campaign entry."""

from __future__ import annotations

import copy
import dataclasses
import math
import re
import tomllib
from importlib import resources
from pathlib import Path

import pytest

from ftcap_hil.config.campaign import load_campaign, parse_campaign
from ftcap_hil.config.mission import load_mission
from ftcap_hil.config.presets import load_preset
from ftcap_hil.config.scenario import load_scenario, parse_scenario
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.runtime.campaign_plan import dumps_toml, plan_campaign

SHIPPED_L_M = 1.255  # CyberShip II's length overall, [hull] l_oa_m of its preset


def _preset_text(length_m: float) -> str:
    """The shipped CyberShip II preset with another length overall (to tell the files apart)."""
    text = resources.files("ftcap_hil.data.vessels").joinpath("cybership2.toml").read_text()
    assert f"l_oa_m = {SHIPPED_L_M}" in text
    return text.replace(f"l_oa_m = {SHIPPED_L_M}", f"l_oa_m = {length_m}")


def _scenario_doc(preset: str) -> dict:
    """The shipped CyberShip II station keeping with ``[plant] preset = preset``, 2 s long."""
    text = resources.files("ftcap_hil.data.scenarios").joinpath("cybership2-station.toml")
    doc = tomllib.loads(text.read_text())
    doc["plant"]["preset"] = preset
    doc["scenario"]["duration"] = 2.0
    return doc


@pytest.fixture
def user_files(tmp_path: Path) -> Path:
    """``a/``: a scenario naming ``presets/mine.toml`` (l_oa_m 2.5) and one naming the
    shipped ``cybership2``; ``b/``: a campaign running the first from ``../a`` and, with
    ``[scenario.set.plant] preset``, its own ``theirs.toml`` (l_oa_m 3.0)."""
    (tmp_path / "a" / "presets").mkdir(parents=True)
    (tmp_path / "b").mkdir()
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "a" / "presets" / "mine.toml").write_text(_preset_text(2.5))
    (tmp_path / "a" / "user.toml").write_text(dumps_toml(_scenario_doc("presets/mine.toml")))
    (tmp_path / "a" / "shipped.toml").write_text(dumps_toml(_scenario_doc("cybership2")))
    (tmp_path / "b" / "theirs.toml").write_text(_preset_text(3.0))
    (tmp_path / "b" / "campaign.toml").write_text(
        '[campaign]\nname = "paths"\nseeds = [1]\nmodes = ["ftcap"]\n\n'
        '[[scenario]]\nsource = "../a/user.toml"\nlabel = "mine"\n\n'
        '[[scenario]]\nsource = "../a/user.toml"\nlabel = "theirs"\n'
        '[scenario.set.plant]\npreset = "theirs.toml"\n'
    )
    return tmp_path


def test_a_relative_preset_path_is_read_from_the_scenario_files_folder(
    user_files: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(user_files / "elsewhere")
    assert load_scenario(user_files / "a" / "user.toml").length_m == 2.5
    monkeypatch.chdir(user_files / "a")  # the only directory it was read from before
    assert load_scenario("user.toml").length_m == 2.5
    # a shipped preset's name is no path
    assert load_scenario(user_files / "a" / "shipped.toml").length_m == SHIPPED_L_M


def test_a_campaigns_runs_and_replays_read_the_presets_from_any_directory(
    user_files: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(user_files / "elsewhere")
    out = user_files / "out"
    plan, files = plan_campaign(load_campaign(user_files / "b" / "campaign.toml"), out)
    lengths = {t.label: t.scenario.length_m for t in plan.tasks}
    assert lengths == {"mine": 2.5, "theirs": 3.0}  # the campaign's own preset: its folder
    (out / "replay").mkdir(parents=True)
    for name, text in files.items():
        (out / "replay" / name).write_text(text)
    monkeypatch.chdir(user_files)  # a replay is run from anywhere
    for task in plan.tasks:
        replay = Path(task.replay.split()[2])
        assert load_scenario(replay).length_m == lengths[task.label]


def test_a_missions_realistic_scenario_reads_its_preset_from_the_scenarios_folder(
    user_files: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (user_files / "b" / "mission.toml").write_text('[mission]\nscenario = "../a/user.toml"\n')
    monkeypatch.chdir(user_files / "elsewhere")
    assert load_mission(user_files / "b" / "mission.toml").scenario.length_m == 2.5


LEVELS = {
    "current": {"speed_m_s": 0.15, "direction_deg": 90.0},
    "waves": {"hs_m": 0.05},
}


def test_environment_levels_from_the_scenario_replace_the_presets_one_by_one() -> None:
    doc = _scenario_doc("cybership2")
    doc["environment"] = LEVELS
    env = parse_scenario(doc, "strong.toml").truth.environment
    own = load_preset("cybership2").environment
    assert env is not None and own.current.speed_m_s != 0.15
    assert env.current.speed_m_s == 0.15 and env.current.direction_rad == math.pi / 2
    assert env.current == dataclasses.replace(
        own.current, speed_m_s=0.15, direction_rad=math.pi / 2
    )
    assert env.waves == dataclasses.replace(own.waves, hs_m=0.05)  # tp_s, gamma: the preset's
    assert env.wind == own.wind
    # without [environment]: the preset's levels
    plain = parse_scenario(_scenario_doc("cybership2"), "plain.toml").truth.environment
    assert plain is not None and plain.current == own.current and plain.waves == own.waves


@pytest.mark.parametrize(
    ("levels", "message"),
    [
        (
            {"current": {"sped_m_s": 0.1}},
            "strong.toml: [environment.current] unknown key 'sped_m_s' (did you mean 'speed_m_s'?)",
        ),
        ({"tide": {"speed_m_s": 0.1}}, "strong.toml: [environment] unknown key 'tide'"),
        ({"waves": {"hs_m": "high"}}, "strong.toml: [environment.waves] hs_m: expected"),
        ({"wind": {"speed_m_s": -1.0}}, "strong.toml: [environment] wind.speed_m_s: must be"),
    ],
)
def test_environment_levels_are_read_strictly(levels: dict, message: str) -> None:
    doc = _scenario_doc("cybership2")
    doc["environment"] = levels
    with pytest.raises(ConfigError, match=re.escape(message)):
        parse_scenario(doc, "strong.toml")


CAMPAIGN = """
[campaign]
name = "current"
seeds = [1]
modes = ["ftcap"]
duration = 2.0

[[scenario]]
source = "cybership2-station"
label = "shipped-current"

[[scenario]]
source = "cybership2-station"
label = "strong-current"
[scenario.set.environment.current]
speed_m_s = 0.15
direction_deg = 90.0
"""


def test_a_campaign_entry_sets_the_environment_levels(tmp_path: Path) -> None:
    plan, files = plan_campaign(parse_campaign(tomllib.loads(CAMPAIGN), "c.toml"), tmp_path)
    speeds = {t.label: t.scenario.truth.environment.current.speed_m_s for t in plan.tasks}
    shipped = load_preset("cybership2").environment.current.speed_m_s
    assert speeds == {"shipped-current": shipped, "strong-current": 0.15}
    strong = [text for name, text in files.items() if name.startswith("strong-current")]
    assert strong and all("[environment.current]" in text for text in strong)  # replayed too
    with pytest.raises(ConfigError, match=re.escape(
        "c.toml: scenario strong-current: [environment.current] unknown key 'direction'"
    )):  # fmt: skip
        bad = CAMPAIGN.replace("direction_deg", "direction")
        plan_campaign(parse_campaign(tomllib.loads(bad), "c.toml"), tmp_path)


@pytest.mark.parametrize(
    ("table", "message"),
    [
        (
            "vessel",
            "unknown table 'vessel' in a realistic scenario: the thrusters are the preset's",
        ),
        (
            "noise",
            "unknown table 'noise' in a realistic scenario: the sensor noise is the preset's",
        ),
    ],
)
def test_a_plain_scenarios_vessel_or_noise_table_is_refused_not_replaced(
    table: str, message: str
) -> None:
    doc = _scenario_doc("cybership2")
    doc[table] = {"preset": "paper-4.2"} if table == "vessel" else {"state_std": [0.1] * 6}
    with pytest.raises(ConfigError, match=re.escape(f"r.toml: {message}")):
        parse_scenario(doc, "r.toml")


def test_a_missing_preset_names_the_scenario_file_the_key_and_the_path(tmp_path: Path) -> None:
    (tmp_path / "r.toml").write_text(dumps_toml(_scenario_doc("presets/missing.toml")))
    want = f"{tmp_path / 'r.toml'}: [plant] preset: vessel preset '{tmp_path / 'presets'}"
    with pytest.raises(ConfigError, match=re.escape(want)):
        load_scenario(tmp_path / "r.toml")


DOCS = Path(__file__).resolve().parents[2] / "docs" / "scenarios.md"


def _docs_section() -> tuple[str, list[str]]:
    """docs/scenarios.md's "Realistic scenarios" section and its TOML blocks."""
    text = DOCS.read_text()
    section = text[text.index("## Realistic scenarios") : text.index("## Strict keys")]
    return section, re.findall(r"```toml\n(.*?)```", section, re.S)


def _valid_keys(doc: dict, table: str) -> list[str]:
    """The keys the reader knows in ``table`` (dotted), from its unknown-key message."""
    target = doc = copy.deepcopy(doc)
    for part in table.split("."):
        target = target.setdefault(part, {})
    target["zz_unknown"] = 1
    with pytest.raises(ConfigError, match=re.escape(f"[{table}] unknown key 'zz_unknown'")) as e:
        parse_scenario(doc, "docs.toml")
    return str(e.value).split("valid keys: ")[1].split(", ")


# [diagnosis] is DiagnosisConfig's, as the section says, not listed key by key
TABLES = ("plant", "conditions", "mismatch", "sensor", "controller", "uncertainty")
TABLES += ("environment.current", "environment.wind", "environment.waves")


def test_the_docs_section_shows_what_the_reader_reads() -> None:
    section, blocks = _docs_section()
    example = tomllib.loads(blocks[0])
    # every table and key of the example is one the reader takes ...
    sc = parse_scenario({**_scenario_doc("cybership2"), **example}, "docs.toml")
    assert sc.truth.environment.current.speed_m_s == example["environment"]["current"]["speed_m_s"]
    # ... and every key the reader takes is in the section
    for table in TABLES:
        for key in _valid_keys({**_scenario_doc("cybership2"), **example}, table):
            shown = (f"`{key}`", f"\n{key} = ", f"# {key} = ")
            assert any(form in section for form in shown), (table, key)
    # the campaign example plans, with its level
    campaign = '[campaign]\nname = "docs"\nseeds = [1]\nmodes = ["ftcap"]\nduration = 2.0\n'
    campaign += blocks[1] + '\n[faults]\nkinds = ["dead"]\nonset = [1.0, 1.5]\n'
    plan, _ = plan_campaign(parse_campaign(tomllib.loads(campaign), "docs.toml"), Path("unused"))
    assert {t.scenario.truth.environment.current.speed_m_s for t in plan.tasks} == {0.15}
