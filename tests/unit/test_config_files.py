"""Every file kind the project reads refuses an unknown key, naming the file, the table,
the key and the nearest valid key; every shipped file still loads; bad values end the
commands with exit code 2 and one line."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from importlib import resources
from pathlib import Path

import pytest

from ftcap_hil.config.bridges import allocator_ports_from, vessel_ports_from
from ftcap_hil.config.campaign import load_campaign, shipped_campaigns
from ftcap_hil.config.daemon import load_daemon_config
from ftcap_hil.config.mission import GCS_KEYS, MISSION_KEYS, load_mission, shipped_missions
from ftcap_hil.config.presets import load_preset, preset_names
from ftcap_hil.config.scenario import load_scenario, shipped_scenarios
from ftcap_hil.config.sim import load_config
from ftcap_hil.config.tables import Table
from ftcap_hil.config.toml import shipped_config
from ftcap_hil.config.vessel import load_vessel
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.estimation.config import BiasCompensation, EstimatorKind
from ftcap_hil.core.models.plants import Inversion, SurfaceVessel
from ftcap_hil.core.scenario import Integrator, TimeUnit
from ftcap_hil.core.status import Mode

DATA = Path(str(resources.files("ftcap_hil").joinpath("data")))
EX1 = (DATA / "scenarios" / "paper-4.2-ex1.toml").read_text()


def raises(message: str) -> pytest.RaisesContext[ConfigError]:
    return pytest.raises(ConfigError, match=re.escape(message))


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# ------------------------------------------------------------------ unknown keys per kind


def test_scenario_fault_untill_is_refused(tmp_path: Path) -> None:
    """The typo that silently made a bounded fault permanent."""
    assert "until = 200.0" in EX1
    path = write(tmp_path, "scenario.toml", EX1.replace("until = 200.0", "untill = 200.0"))
    with raises("scenario.toml: [[fault]][0] unknown key 'untill' (did you mean 'until'?)"):
        load_scenario(path)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('integrator = "euler"', 'intgrator = "euler"', "[scenario] unknown key 'intgrator'"),
        ("kp = 0.75", "kpp = 0.75", "[controller] unknown key 'kpp' (did you mean 'kp'?)"),
        ("[[reference]]", "[[reference]]\nfrm = 1.0", "[[reference]][0] unknown key 'frm'"),
        ("mass_kg = 1.1274", "mas_kg = 1.1274", "[plant] unknown key 'mas_kg'"),
        ("l = 0.3", "ll = 0.3", "[vessel] unknown key 'll' (did you mean 'l'?)"),
        ("[plant]", "[noise]\nstd = 0.1\n[plant]", "[noise] unknown key 'std'"),
        ("[plant]", "[noize]\n[plant]", "unknown table 'noize' (did you mean 'noise'?)"),
        ("[plant]", "[allocation]\n[plant]", "table [allocation] is now called [allocator]"),
        (
            "[plant]",
            "[estimator]\nmeasurement_std = [0.001, 0.001]\n[plant]",
            "[estimator] measurement_std: expected 3 or 6 numbers >= 0, got [0.001, 0.001]",
        ),
    ],
)
def test_scenario_tables_refuse_unknown_keys(tmp_path: Path, old: str, new: str, message: str):
    assert old in EX1
    path = write(tmp_path, "scenario.toml", EX1.replace(old, new, 1))
    with raises(f"scenario.toml: {message}"):
        load_scenario(path)


CS2 = (DATA / "scenarios" / "cybership2-station.toml").read_text()


@pytest.mark.parametrize("text", [EX1, CS2], ids=["plain", "realistic"])
def test_estimation_period_s_is_read_in_any_scenario(tmp_path: Path, text: str) -> None:
    head = "[scenario]\n"
    assert head in text
    path = write(tmp_path, "s.toml", text.replace(head, head + "estimation_period_s = 0.0\n", 1))
    with raises("s.toml: [scenario] estimation_period_s: expected a finite number > 0"):
        load_scenario(path)
    dt = load_scenario(write(tmp_path, "ok.toml", text)).dt_s
    ok = text.replace(head, head + f"estimation_period_s = {5 * dt!r}\n", 1)
    assert load_scenario(write(tmp_path, "ok.toml", ok)).estimation_period_s == 5 * dt
    bad = text.replace(head, head + f"estimation_period_s = {2.5 * dt!r}\n", 1)
    with raises(f"s.toml: [scenario] estimation_period_s: expected a multiple of dt ({dt} s)"):
        load_scenario(write(tmp_path, "s.toml", bad))


@pytest.mark.parametrize("text", [EX1, CS2], ids=["plain", "realistic"])
def test_the_old_estimation_period_key_is_an_unknown_key(tmp_path: Path, text: str) -> None:
    head = "[scenario]\n"
    path = write(tmp_path, "s.toml", text.replace(head, head + "estimation_period = 1.0\n", 1))
    with raises(
        "s.toml: [scenario] unknown key 'estimation_period' (did you mean 'estimation_period_s'?)"
    ):
        load_scenario(path)


def test_linear_scenario_refuses_a_vessel_table(tmp_path: Path) -> None:
    text = (DATA / "scenarios" / "paper-4.1.toml").read_text()
    path = write(tmp_path, "linear.toml", text + '\n[vessel]\npreset = "paper-4.2"\n')
    with raises("linear.toml: unknown table 'vessel'; valid tables: actuators, allocator"):
        load_scenario(path)


def test_vessel_file_refuses_unknown_keys(tmp_path: Path) -> None:
    thruster = 'name = "A"\nx = 0.0\ny = 0.0\nangle_deg = 0.0\nu_min = -1.0\nu_max = 1.0\n'
    good = write(tmp_path, "boat.toml", f"[vessel]\n[[vessel.thruster]]\n{thruster}")
    assert load_vessel(good).m == 1
    bad = write(tmp_path, "bad.toml", f"[vessel]\n[[vessel.thruster]]\n{thruster}u_maxx = 2\n")
    with raises("bad.toml: [[vessel.thruster]][0] unknown key 'u_maxx' (did you mean 'u_max'?)"):
        load_vessel(bad)
    top = write(tmp_path, "top.toml", 'preset = "paper-4.2"\nlimit = 0.1\n')
    with raises("top.toml: unknown key 'limit'"):
        load_vessel(top)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("daemon.rate_hzz=3", "[daemon] unknown key 'rate_hzz' (did you mean 'rate_hz'?)"),
        ("allocator.backnd='daqp'", "[allocator] unknown key 'backnd' (did you mean 'backend'?)"),
        ("allocation.backend='daqp'", "table [allocation] is now called [allocator]"),
        ("can.chanel='x'", "[can] unknown key 'chanel' (did you mean 'channel'?)"),
        ("zenoh.vesel='x'", "[zenoh] unknown key 'vesel' (did you mean 'vessel'?)"),
        ("mavlink.sysid=3", "[mavlink] unknown key 'sysid' (did you mean 'system_id'?)"),
        ("estimator.windw=3", "[estimator] unknown key 'windw' (did you mean 'window'?)"),
        ("excitation.seeed=3", "[excitation] unknown key 'seeed' (did you mean 'seed'?)"),
        ("plant.mass=3", "[plant] unknown key 'mass' (did you mean 'mass_kg'?)"),
        ("daemon.mode='oracle'", "[daemon] mode: 'oracle' needs the true faults"),
        ("allocator.backend='daqpp'", "[allocator] backend: 'daqpp' is not one of 'daqp'"),
        ("daemon.wake_on_setpoint=1", "[daemon] wake_on_setpoint: expected true or false, got 1"),
        ("can.esc_node_ids=[20, 21]", "[can] esc_node_ids: expected a list of 4 integers in"),
        ("can.node_id=0", "[can] node_id: expected an integer in 1..127, got 0"),
        ("mavlink.max_wrench=[1, 0, 1]", "[mavlink] max_wrench: expected 3 finite numbers > 0"),
        ("zenoh.config='nope.json5'", "[zenoh] config: 'nope.json5': no such file, nor a"),
    ],
)
def test_allocator_file_refuses_unknown_keys_and_bad_values(override: str, message: str):
    with raises(f"allocator.toml: {message}"):
        load_daemon_config(None, [override])


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("sim.rate_hzz=3", "[sim] unknown key 'rate_hzz' (did you mean 'rate_hz'?)"),
        ("esc.kr_pm=3", "[esc] unknown key 'kr_pm' (did you mean 'k_rpm'?)"),
        (
            "can.node_id=10",
            "[can] unknown key 'node_id' (did you mean 'esc_node_ids'?); valid keys: allocator_",
        ),
        ("zenoh.conect='tcp/127.0.0.1:1'", "[zenoh] unknown key 'conect' (did you mean"),
        ("mavlink.max_wrench=[1, 1, 1]", "[mavlink] unknown key 'max_wrench'"),
        ("vessel.u_limt=1", "[vessel] unknown key 'u_limt' (did you mean 'u_limit'?)"),
    ],
)
def test_sim_file_refuses_unknown_keys(override: str, message: str) -> None:
    with raises(f"vessel.toml: {message}"):
        load_config(None, [override])


def test_mission_refuses_unknown_keys(tmp_path: Path) -> None:
    head = '[mission]\nscenario = "paper-4.2-ex1"\nduraton = 10.0\n'
    with raises("m.toml: [mission] unknown key 'duraton' (did you mean 'duration'?)"):
        load_mission(write(tmp_path, "m.toml", head))
    fault = '[mission]\nscenario = "paper-4.2-ex1"\n[[fault]]\nfrom = 1.0\nuntill = 2.0\n'
    with raises("f.toml: [[fault]][0] unknown key 'untill' (did you mean 'until'?)"):
        load_mission(write(tmp_path, "f.toml", fault))
    with raises("g.toml: unknown table 'gsc' (did you mean 'gcs'?)"):
        load_mission(write(tmp_path, "g.toml", '[mission]\nscenario = "paper-4.2-ex1"\n[gsc]\n'))


def test_mission_names_the_scenario_file_for_the_scenario_tables(tmp_path: Path) -> None:
    write(tmp_path, "sc.toml", EX1.replace("k_eta = 0.63", "k_eta = 0.63\nk_et = 1.0"))
    with raises("sc.toml: [controller] unknown key 'k_et' (did you mean 'k_eta'?)"):
        load_mission(write(tmp_path, "m.toml", '[mission]\nscenario = "sc.toml"\n'))


def test_mission_keys_are_what_the_reader_reads() -> None:
    """tests/docker checks --set keys against MISSION_KEYS / GCS_KEYS."""
    for table, keys in (("mission", MISSION_KEYS), ("gcs", GCS_KEYS)):
        with pytest.raises(ConfigError) as info:
            load_mission("paper-4.2-ex1", [f"{table}.zzz=1"])
        listed = str(info.value).split("valid keys: ")[1].split(", ")
        assert listed == sorted(keys)


def test_zenoh_json5_refuses_unknown_keys(tmp_path: Path) -> None:
    from bridges.zenoh_io.config import ZenohConfigError
    from bridges.zenoh_io.session import load_config as load_zenoh

    text = (DATA / "zenoh" / "allocator.json5").read_text()
    assert "gossip: { enabled: false }" in text
    path = write(tmp_path, "z.json5", text.replace("gossip: {", "gosip: {"))
    with pytest.raises(
        ZenohConfigError, match=re.escape("z.json5: [scouting] unknown key 'gosip'")
    ):
        load_zenoh(path)
    top = write(tmp_path, "t.json5", text.replace("listen: {", "lisen: {"))
    with pytest.raises(ZenohConfigError, match="unknown key 'lisen' .did you mean 'listen'.."):
        load_zenoh(top)
    with pytest.raises(ZenohConfigError, match=re.escape("[scouting] unknown key 'multicst'")):
        load_zenoh(DATA / "zenoh" / "gcs.json5", ["scouting/multicst/enabled:false"])


# ------------------------------------------------------------------ bridge tables


def _root(text: str) -> Table:
    from ftcap_hil.config.toml import parse_toml

    return Table(parse_toml(text, "f.toml"), "f.toml")


def test_bridge_tables_build_the_port_settings() -> None:
    root = _root(
        '[can]\nchannel = "127.0.0.1:1"\nesc_node_ids = [30, 31]\n'
        '[mavlink]\nconnection = "udpin:127.0.0.1:15000"\npeers = ["127.0.0.1:15001"]\n'
        '[zenoh]\nconnect = "tcp/127.0.0.1:7448"\noverrides = ["mode:\\"client\\""]\n'
    )
    ports = vessel_ports_from(root, 2)
    root.finish()
    assert ports.can.channel == "127.0.0.1:1" and ports.can.esc_node_ids == (30, 31)
    assert ports.mavlink is not None and ports.mavlink.endpoint.system_id == 1
    assert ports.mavlink.endpoint.peers == ("127.0.0.1:15001",)
    assert ports.zenoh is not None and ports.zenoh.config.name == "vessel.json5"
    assert ports.zenoh.overrides == (
        'connect/endpoints:["tcp/127.0.0.1:7448"]',
        'mode:"client"',
    )
    off = _root("[mavlink]\nenabled = false\nsystem_id = 3\n[zenoh]\nenabled = false\n")
    ports = allocator_ports_from(off, 4)
    off.finish()
    assert ports.mavlink is None and ports.zenoh is None and ports.can.esc_node_ids is None


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[mavlink]\nsystem_id = 0", "[mavlink] system_id: expected an integer in 1..255, got 0"),
        ('[mavlink]\npeers = ["localhost"]', "[mavlink] peers: expected 'host:port', got"),
        ('[mavlink]\npeers = "127.0.0.1:1"', "[mavlink] peers: expected a list of strings"),
        ('[mavlink]\nconnection = "udpout:127.0.0.1:1"', "[mavlink] peers: only a 'udpin:'"),
        ("[can]\nesc_node_ids = [20, 20]", "[can] esc_node_ids: expected distinct node IDs"),
        ("[can]\ndeadband_n = -1", "[can] deadband_n: expected a finite number >= 0, got -1"),
        ('[can]\ninterface = "socketcan"\nstart_hub = true', "[can] start_hub: true needs"),
        ('[zenoh]\noverrides = ["x"]', "[zenoh] overrides: --cfg 'x': expected KEY:VALUE"),
        ("[zenoh]\nconnect = 3", "[zenoh] connect: expected a non-empty string, got 3"),
    ],
)
def test_bridge_tables_name_bad_values(text: str, message: str) -> None:
    with raises(f"f.toml: {message}"):
        vessel_ports_from(_root(text), 2)


@pytest.mark.parametrize(
    ("table", "shown"),
    [
        ('connection = "udpin:0.0.0.0:15000"\nbind_all_interfaces = true',
         "connection = 'udpin:0.0.0.0:15000'"),
        ('connection = "udpin:192.0.2.7:15000"', "connection = 'udpin:192.0.2.7:15000'"),
        ('peers = ["192.0.2.8:14550"]', "peers contains '192.0.2.8:14550'"),
        ('relay = ["gcs.boat.lan:14560"]', "relay contains 'gcs.boat.lan:14560'"),
    ],
)  # fmt: skip
def test_an_unsigned_mavlink_link_beyond_loopback_is_refused_unless_allowed(
    table: str, shown: str
) -> None:
    """Secure by default (issue 33): a bind, peer or relay off this machine's loopback
    without a signing key stops the start with the file, table and key; the explicit
    opt-out starts, with the warning it is logged with; a key file needs no opt-out."""
    for reader in (vessel_ports_from, allocator_ports_from):
        with raises(f"f.toml: [mavlink] key_file: unset, and {shown} reaches beyond loopback"):
            reader(_root(f"[mavlink]\n{table}\n"), 4)
        allowed = reader(_root(f"[mavlink]\n{table}\nallow_unauthenticated = true\n"), 4)
        assert allowed.mavlink is not None and allowed.mavlink.unauthenticated == shown
        assert allowed.mavlink.warning is not None and shown in allowed.mavlink.warning
        signed = reader(_root(f'[mavlink]\n{table}\nkey_file = "/etc/k.key"\n'), 4)
        assert signed.mavlink is not None and signed.mavlink.warning is None
    local = allocator_ports_from(_root('[mavlink]\nconnection = "udpin:[::1]:15000"\n'), 4)
    assert local.mavlink is not None and local.mavlink.warning is None


def test_a_zenoh_endpoint_beyond_loopback_needs_mtls_and_access_control() -> None:
    """Plain tcp to a router elsewhere is refused naming the key and the opt-out; allowed, it
    is only warned about; tls with mutual TLS (and on a router, access control denying by
    default) passes; loopback and unix sockets never count."""
    from bridges.zenoh_io.config import ZenohConfigError, ZenohRole, check_settings

    client = {
        "mode": "client", "scouting/multicast/enabled": False,
        "connect/endpoints": ["tcp/zenoh:7447"],
    }  # fmt: skip
    with pytest.raises(ZenohConfigError, match=re.escape(
        "c.json5: connect/endpoints contains 'tcp/zenoh:7447', beyond loopback without "
        "mutual TLS and access control"
    )):  # fmt: skip
        check_settings(client, "c.json5")
    with pytest.raises(ZenohConfigError, match="allow_unauthenticated = true"):
        check_settings(client, "c.json5")
    assert check_settings(client, "c.json5", allow_unauthenticated=True) is ZenohRole.CLIENT
    tls = {**client, "connect/endpoints": ["tls/boat.lan:7447"]}
    with pytest.raises(ZenohConfigError):
        check_settings(tls)  # tls without mutual authentication: anyone may connect
    assert check_settings({**tls, "transport/link/tls/enable_mtls": True}) is ZenohRole.CLIENT
    router = {
        "mode": "router", "scouting/multicast/enabled": False,
        "listen/endpoints": ["tls/192.0.2.9:7447"], "transport/link/tls/enable_mtls": True,
    }  # fmt: skip
    with pytest.raises(ZenohConfigError, match="listen/endpoints contains 'tls/192.0.2.9"):
        check_settings(router)  # no access control: any certified client puts anything
    acl = {"access_control/enabled": True, "access_control/default_permission": "deny"}
    assert check_settings({**router, **acl}) is ZenohRole.ROUTER
    local = {**router, "listen/endpoints": ["tcp/127.0.0.1:7447", "unixsock-stream//tmp/z"]}
    assert check_settings(local) is ZenohRole.ROUTER


# ------------------------------------------------------------------ shipped files


def test_every_shipped_file_loads() -> None:
    for name in shipped_scenarios():
        assert load_scenario(name).name == name
    for name in shipped_missions():
        assert load_mission(name).name == name
    daemon = load_daemon_config(None)
    assert daemon.ports.mavlink is not None and daemon.ports.zenoh is not None
    assert daemon.daemon.core.allocator.backend == "daqp"
    vessel = load_config(None, [])
    assert vessel.ports.can.esc_node_ids == (20, 21, 22, 23)
    assert {"cybership2", "supply"} <= set(preset_names())
    for name in preset_names():
        assert load_preset(name).thrusters.m > 3
    for name in shipped_campaigns():
        assert load_campaign(name).source
    assert shipped_config("allocator.toml").is_file()


def test_every_shipped_zenoh_config_loads() -> None:
    from bridges.zenoh_io.session import load_config as load_zenoh

    loaded = {
        name: load_zenoh(DATA / "zenoh" / f"{name}.json5")
        for name in ("allocator", "vessel", "gcs")
    }
    for name, mode, listen, connect in [
        ("allocator", "router", ["tcp/127.0.0.1:7447"], []),
        ("vessel", "client", [], ["tcp/127.0.0.1:7447"]),
        ("gcs", "client", [], ["tcp/127.0.0.1:7447"]),
    ]:
        conf = loaded[name]
        assert json.loads(conf.get_json("mode")) == mode, name
        assert json.loads(conf.get_json("listen/endpoints")) == listen, name
        assert json.loads(conf.get_json("connect/endpoints")) == connect, name
        assert json.loads(conf.get_json("scouting/multicast/enabled")) is False, name


# ------------------------------------------------------------------ the commands


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["simulate", "SCENARIO", "--out", "OUT"], "[allocator] backend: 'daqpp' is not one of"),
        (["allocator", "--set", "daemon.rate_hzz=3"], "[daemon] unknown key 'rate_hzz'"),
        (["sim", "--set", "sim.rate_hz=-1"], "[sim] rate_hz: expected a finite number > 0"),
        (["gcs", "--set", "gcs.colour=1"], "[gcs] unknown key 'colour'"),
    ],
)
def test_bad_values_exit_2_with_one_line(tmp_path: Path, argv: list[str], message: str) -> None:
    scenario = write(tmp_path, "s.toml", EX1 + '\n[allocator]\nbackend = "daqpp"\n')
    argv = [str(scenario) if a == "SCENARIO" else str(tmp_path) if a == "OUT" else a for a in argv]
    if argv[0] == "gcs":
        argv += ["--mission", "paper-4.2-ex1"]
    out = subprocess.run(
        [sys.executable, "-m", "ftcap_hil", *argv], capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 2, out.stderr
    lines = [line for line in out.stderr.splitlines() if "SLCAN" not in line]
    assert len(lines) == 1 and message in lines[0], out.stderr
    assert "Traceback" not in out.stderr


def test_mode_names_the_choices() -> None:
    with pytest.raises(ConfigError) as info:
        load_mission("paper-4.2-ex1", ["mission.mode='turbo'"])
    for mode in Mode:
        assert (repr(mode.value) in str(info.value)) is (mode is not Mode.ORACLE)


# ------------------------------------------------------------------ string switches as enums


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            "[plant]",
            '[estimator]\nkind = "kalmann"\n[plant]',
            "[estimator] kind: 'kalmann' is not one of 'kalman', 'windowed' (did you mean",
        ),
        (
            "[plant]",
            '[estimator]\nbias_compensation = "some"\n[plant]',
            "[estimator] bias_compensation: 'some' is not one of 'attributed', 'all'",
        ),
        (
            "mass_kg = 1.1274",
            'mass_kg = 1.1274\ninversion = "midpoint"',
            "[plant] inversion: 'midpoint' is not one of 'euler', 'trapezoid'",
        ),
        (
            'integrator = "euler"',
            'integrator = "rk5"',
            "[scenario] integrator: 'rk5' is not one of 'euler', 'rk4' (did you mean 'rk4'?)",
        ),
        (
            'kind = "vessel"',
            'kind = "boat"',
            "[plant] kind: 'boat' is not one of 'linear', 'vess",
        ),
    ],
)
def test_a_bad_switch_names_file_table_key_and_choices(
    tmp_path: Path, old: str, new: str, message: str
) -> None:
    assert old in EX1
    path = write(tmp_path, "scenario.toml", EX1.replace(old, new, 1))
    with raises(f"scenario.toml: {message}"):
        load_scenario(path)


def test_the_files_spelling_reads_as_the_enum(tmp_path: Path) -> None:
    extra = '[estimator]\nkind = "windowed"\nbias_compensation = "all"\n[plant]'
    text = EX1.replace("[plant]", extra, 1).replace('integrator = "euler"', 'integrator = "rk4"')
    text = text.replace("mass_kg = 1.1274", 'mass_kg = 1.1274\ninversion = "trapezoid"')
    sc = load_scenario(write(tmp_path, "scenario.toml", text))
    assert sc.core.estimator.kind is EstimatorKind.WINDOWED
    assert sc.core.estimator.bias_compensation is BiasCompensation.ALL
    assert sc.integrator is Integrator.RK4 and sc.time_unit is TimeUnit.SECOND
    assert isinstance(sc.plant, SurfaceVessel) and sc.plant.inversion is Inversion.TRAPEZOID
    assert load_scenario("paper-4.1").time_unit is TimeUnit.STEP
    realistic = load_scenario("cybership2-station")
    assert realistic.integrator is Integrator.RK4
    assert realistic.plant.inversion is Inversion.TRAPEZOID  # type: ignore[union-attr]
