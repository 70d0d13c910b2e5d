"""Zenoh configuration: shipped files, role defaults, --cfg overrides and the network policy.

Configs are real ``zenoh.Config`` objects (parsed by zenoh itself); no session is opened here.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import zenoh

from bridges.zenoh_io.config import (
    SHIPPED_CONFIGS,
    ZenohConfigError,
    ZenohRole,
    binds_all_interfaces,
    check_settings,
    endpoint_host,
    parse_override,
    shipped_config_path,
)
from bridges.zenoh_io.link import apply_overrides, load_config, make_config, validate_config

EXPECTED_ROLE = {"allocator": ZenohRole.ROUTER, "vessel": ZenohRole.CLIENT, "gcs": ZenohRole.CLIENT}


def endpoints(conf: zenoh.Config, key: str) -> object:
    return json.loads(conf.get_json(key))


@pytest.mark.parametrize("name", SHIPPED_CONFIGS)
def test_every_shipped_config_passes_the_validator(name: str) -> None:
    conf = load_config(shipped_config_path(name))
    assert validate_config(conf) is EXPECTED_ROLE[name.removesuffix("-tls")]
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    key = "listen/endpoints" if name.startswith("allocator") else "connect/endpoints"
    proto = "tls" if name.endswith("-tls") else "tcp"
    assert endpoints(conf, key) == [f"{proto}/127.0.0.1:7447"]
    assert json.loads(conf.get_json("transport/shared_memory/enabled")) is False


def test_shipped_config_directory_holds_only_checked_files() -> None:
    found = {p.stem for p in shipped_config_path("allocator").parent.glob("*.json5")}
    assert found == set(SHIPPED_CONFIGS)


def test_router_config_listens_on_loopback_port() -> None:
    conf = make_config("router", port=17999)
    assert endpoints(conf, "listen/endpoints") == ["tcp/127.0.0.1:17999"]
    assert json.loads(conf.get_json("mode")) == "router"
    assert json.loads(conf.get_json("scouting/gossip/enabled")) is False


@pytest.mark.parametrize("role", ["client", "peer"])
def test_client_and_peer_configs_connect_and_never_listen(role: str) -> None:
    conf = make_config(role, port=17999)
    assert endpoints(conf, "connect/endpoints") == ["tcp/127.0.0.1:17999"]
    assert endpoints(conf, "listen/endpoints") == []


def test_override_moves_a_shipped_config_to_another_port() -> None:
    cfg = ['connect/endpoints:["tcp/127.0.0.1:18000"]', "connect/timeout_ms:500"]
    conf = load_config(shipped_config_path("vessel"), cfg)
    assert endpoints(conf, "connect/endpoints") == ["tcp/127.0.0.1:18000"]


@pytest.mark.parametrize("value", ["true", "null"])
def test_validator_refuses_multicast_scouting(value: str) -> None:
    with pytest.raises(ZenohConfigError, match="scouting/multicast/enabled"):
        load_config(shipped_config_path("gcs"), [f"scouting/multicast/enabled:{value}"])


@pytest.mark.parametrize(
    "locator", ["tcp/0.0.0.0:7447", "tcp/[::]:7447", "udp/0.0.0.0:7447", "tcp/:7447"]
)
def test_validator_refuses_listening_on_all_interfaces(locator: str) -> None:
    cfg = [f"listen/endpoints:{json.dumps([locator])}"]
    with pytest.raises(ZenohConfigError, match="listen/endpoints") as info:
        load_config(shipped_config_path("allocator"), cfg)
    assert locator in str(info.value)


def test_validator_refuses_zenoh_defaults() -> None:
    # zenoh's own defaults: multicast scouting on, a peer listening on tcp/[::]:0
    with pytest.raises(ZenohConfigError, match="scouting/multicast/enabled"):
        validate_config(zenoh.Config())
    conf = zenoh.Config()
    apply_overrides(conf, ["scouting/multicast/enabled:false"])
    with pytest.raises(ZenohConfigError, match=r"listen/endpoints/peer.*\[::\]"):
        validate_config(conf)


def test_validator_refuses_router_without_listener_and_client_without_router() -> None:
    with pytest.raises(ZenohConfigError, match="listen/endpoints"):
        make_config("router", overrides=["listen/endpoints:[]"])
    with pytest.raises(ZenohConfigError, match="connect/endpoints"):
        make_config("client", overrides=["connect/endpoints:[]"])


def test_bad_overrides_name_the_key() -> None:
    with pytest.raises(ZenohConfigError, match="KEY:VALUE"):
        make_config("client", overrides=["connect/endpoints"])
    with pytest.raises(ZenohConfigError, match="no/such/key"):
        make_config("client", overrides=["no/such/key:1"])
    with pytest.raises(ZenohConfigError, match="role = 'captain'"):
        make_config("captain")


def test_unreadable_config_file_is_a_config_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: 'router', listen: ")
    with pytest.raises(ZenohConfigError, match="bad.json5"):
        load_config(bad)
    with pytest.raises(ZenohConfigError, match="missing.json5"):
        load_config(tmp_path / "missing.json5")


def test_parse_override_splits_at_the_first_colon() -> None:
    assert parse_override('connect/endpoints:["tcp/127.0.0.1:7447"]') == (
        "connect/endpoints",
        '["tcp/127.0.0.1:7447"]',
    )


@pytest.mark.parametrize(
    ("locator", "host", "wildcard"),
    [
        ("tcp/127.0.0.1:7447", "127.0.0.1", False),
        ("tcp/[::1]:7447", "::1", False),
        ("tcp/[::]:0", "::", True),
        ("tcp/[0:0:0:0:0:0:0:0]:7447", "0:0:0:0:0:0:0:0", True),
        ("tcp/0.0.0.0:7447#iface=lo", "0.0.0.0", True),
        ("tcp/localhost:7447", "localhost", False),
        ("unixsock-stream//tmp/zenoh.sock", None, False),
    ],
)
def test_endpoint_hosts(locator: str, host: str | None, wildcard: bool) -> None:
    assert endpoint_host(locator) == host
    assert binds_all_interfaces(locator) is wildcard


def test_check_settings_reads_per_mode_endpoint_maps() -> None:
    values = {
        "mode": "router",
        "scouting/multicast/enabled": False,
        "listen/endpoints": {"router": ["tcp/127.0.0.1:7447"], "peer": ["tcp/[::]:0"]},
    }
    assert check_settings(values) is ZenohRole.ROUTER
    values["listen/endpoints"] = {"router": ["tcp/0.0.0.0:7447"]}
    with pytest.raises(ZenohConfigError, match="listen/endpoints/router"):
        check_settings(values)
