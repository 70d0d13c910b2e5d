"""docker/compose.yaml as local processes: the mapping of the container world and the runner
(no tests here: test_compose_local.py and test_compose.py use it).

:func:`build_world` maps the container world onto this machine, the same way everywhere
(arguments, mounted files, health checks, published ports):

* service names, ``0.0.0.0`` and ``localhost`` -> 127.0.0.1: nothing is bound elsewhere;
* every port the files mention -> one free local port (free for TCP and UDP alike);
* container paths -> local ones: bind-mounted files are copied with the same mapping, files
  the Dockerfile COPYs come from the repository, the ./out mount is a temporary folder, and
  absolute paths in the image's ENV become temporary folders.

:class:`LocalCompose` starts the services in dependency order: ours as the image's
ENTRYPOINT + the service's command (the project's console script, this Python); the
eclipse/zenoh router as a router-mode Zenoh session of the same release opened in a
subprocess from the service's own mounted file (checked by the product's validator as mapped
here); ``service_healthy`` by running the service's own healthcheck command until it passes.
It stops them newest first with SIGTERM, as ``docker stop`` does, and finds leftovers by an
environment marker every child carries.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tests.docker.compose_files import (
    DOCKER,
    EXIT_SERVICE,
    ROOT,
    Image,
    argv_of,
    container_argv,
    depends_on,
    is_ours,
    parse_duration,
    read_image,
)

LOCAL = "127.0.0.1"
MARKER_ENV = "FTCAP_COMPOSE_TEST_RUN"  # set on every child: leftovers are found by it

_PORT_FLAG = re.compile(r"--[\w-]*port$")


@dataclass
class LocalWorld:
    """The consistent mapping of container names, ports and paths onto this machine."""

    root: Path
    hosts: frozenset[str]
    ports: dict[int, int] = field(default_factory=dict)
    paths: dict[str, Path] = field(default_factory=dict)  # in the image (Dockerfile COPY)
    mounts: dict[str, dict[str, Path]] = field(default_factory=dict)  # service -> target -> here

    def _hostport(self) -> re.Pattern[str]:
        names = "|".join(re.escape(h) for h in sorted(self.hosts, key=len, reverse=True))
        return re.compile(rf"(?<![\w.-])(?P<host>{names}):(?P<port>\d{{1,5}})(?!\d)")

    def ports_in(self, text: str) -> set[int]:
        return {int(m["port"]) for m in self._hostport().finditer(text)}

    def text(self, text: str, service: str | None = None) -> str:
        def port(m: re.Match[str]) -> str:
            number = int(m["port"])
            if number not in self.ports:
                raise AssertionError(f"{m[0]!r}: port {number} is in no service's topology")
            return f"{LOCAL}:{self.ports[number]}"

        text = self._hostport().sub(port, text)
        paths = {**self.paths, **self.mounts.get(service or "", {})}
        for container in sorted(paths, key=len, reverse=True):
            pattern = rf"(?<![\w./-]){re.escape(container)}(?=$|/|[\s\"',\]])"
            text = re.sub(pattern, lambda _m, c=container: str(paths[c]), text)
        return text

    def argv(self, argv: list[str], service: str | None = None) -> list[str]:
        out = []
        for i, token in enumerate(argv):
            if i and _PORT_FLAG.match(argv[i - 1]) and token.isdigit():
                number = int(token)
                assert number in self.ports, f"{argv[i - 1]} {token}: port in no topology"
                out.append(str(self.ports[number]))
            else:
                out.append(self.text(token, service))
        return out


def free_port(taken: set[int]) -> int:
    """A port free on 127.0.0.1 for TCP and UDP alike, not in ``taken``."""
    for _ in range(200):
        with (
            socket.socket(socket.AF_INET, socket.SOCK_STREAM) as tcp,
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp,
        ):
            tcp.bind((LOCAL, 0))
            number = tcp.getsockname()[1]
            try:
                udp.bind((LOCAL, number))
            except OSError:
                continue
            if number not in taken:
                return int(number)
    raise RuntimeError("no free port")


def bind_mounts(spec: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Bind mounts as long-syntax dicts (``source`` relative to docker/)."""
    out = []
    for v in spec.get("volumes", []):
        if isinstance(v, str):
            source, target, *mode = v.split(":")
            out.append({"type": "bind", "source": source, "target": target, "mode": mode})
        else:
            out.append(dict(v))
    return [m for m in out if m.get("type") == "bind"]


def health_argv(spec: Mapping[str, Any]) -> list[str]:
    test = spec["healthcheck"]["test"]
    if isinstance(test, str):
        return ["/bin/sh", "-c", test]
    kind, *rest = test
    assert kind in ("CMD", "CMD-SHELL"), f"healthcheck test {test!r}"
    return rest if kind == "CMD" else ["/bin/sh", "-c", " ".join(rest)]


def local_executable(argv: list[str]) -> list[str]:
    """The image's executables here: the project's console script and this Python."""
    head, rest = argv[0], argv[1:]
    if head == "ftcap-hil":
        script = Path(sys.executable).parent / "ftcap-hil"
        return ([str(script)] if script.exists() else [sys.executable, "-m", "ftcap_hil"]) + rest
    if head in ("python", "python3"):
        return [sys.executable, *rest]
    if head == "/bin/sh":
        return argv
    raise AssertionError(f"no local stand-in for the container executable {head!r}")


def _mount_source(m: Mapping[str, Any]) -> tuple[Path, bool]:
    """(source path, is it a folder the user creates first: `mkdir -p out/...`)."""
    source = (DOCKER / m["source"]).resolve()
    user_folder = "out" in source.relative_to(ROOT).parts and not source.is_file()
    return source, user_folder and not m.get("bind", {}).get("create_host_path", True)


def build_world(compose: Mapping[str, Any], image: Image, root: Path) -> LocalWorld:
    """Ports, names and paths of ``compose`` mapped under ``root``; mounted files copied.

    A bind mount must be a file of the repository (copied here with the same mapping) or the
    output folder the user creates (``create_host_path: false``): anything else fails.
    """
    services = compose["services"]
    world = LocalWorld(root, frozenset({*services, "0.0.0.0", "localhost", LOCAL}))
    texts: list[str] = []
    ports: set[int] = set()
    for name, spec in services.items():
        argv = container_argv(spec, image) if is_ours(spec) else argv_of(spec.get("command"))
        if "healthcheck" in spec:
            argv += health_argv(spec)
        texts += argv
        ports |= {int(t) for p, t in zip(argv, argv[1:], strict=False) if _PORT_FLAG.match(p)}
        ports |= {int(str(p).split(":")[-1].split("/")[0]) for p in spec.get("ports", [])}
        for m in bind_mounts(spec):
            source, user_folder = _mount_source(m)
            if source.is_file():
                texts.append(source.read_text())
            elif not user_folder:
                raise AssertionError(f"{name}: mounted file {m['source']} does not exist")
    for text in texts:
        ports |= world.ports_in(text)
    for number in sorted(ports):
        world.ports[number] = free_port(set(world.ports.values()))
    for target, local in image.copies.items():
        assert local.exists(), f"Dockerfile COPY {local.relative_to(ROOT)}: no such file"
        world.paths[target] = local
    for name, spec in services.items():
        mounts = world.mounts.setdefault(name, {})
        for m in bind_mounts(spec):
            source, _ = _mount_source(m)
            local = root / "mounts" / name / Path(m["target"]).name
            local.parent.mkdir(parents=True, exist_ok=True)
            if source.is_file():
                local.write_text(world.text(source.read_text()))
            else:
                local.mkdir()
            mounts[m["target"]] = local
    return world


def local_env(
    service: str, spec: Mapping[str, Any], image: Image, world: LocalWorld, marker: str
) -> dict[str, str]:
    env = dict(os.environ)
    for key, value in image.env.items():
        if key == "PATH":
            continue
        if value.startswith("/"):  # a container path: a private folder here
            value = str(world.root / "env" / key)
            Path(value).mkdir(parents=True, exist_ok=True)
        env[key] = value
    own = spec.get("environment", {})
    items = own.items() if isinstance(own, dict) else (e.split("=", 1) for e in own)
    env.update({k: world.text(str(v), service) for k, v in items})
    env[MARKER_ENV] = marker
    return env


# ---------------------------------------------------------------- running it


ZENOH_ROUTER_STANDIN = """
import signal, sys, threading
import zenoh
stop = threading.Event()
for s in (signal.SIGTERM, signal.SIGINT):
    signal.signal(s, lambda *_: stop.set())
with zenoh.open(zenoh.Config.from_file(sys.argv[1])):
    print("zenoh router stand-in ready", flush=True)
    stop.wait()
"""


def zenoh_router_argv(name: str, spec: Mapping[str, Any], world: LocalWorld) -> list[str]:
    """eclipse/zenoh runs ``zenohd <command>``: only ``--config FILE`` has a stand-in here."""
    image = str(spec.get("image", ""))
    assert image.startswith("eclipse/zenoh:"), f"{name}: no local stand-in for image {image!r}"
    args = world.argv(argv_of(spec.get("command")), name)
    assert len(args) == 2 and args[0] in ("-c", "--config"), f"{name}: zenohd {args}"
    from bridges.zenoh_io.link import load_config

    load_config(args[1])  # the product's own check, on the router config as mapped here
    return [sys.executable, "-c", ZENOH_ROUTER_STANDIN, args[1]]


class ComposeRunError(AssertionError):
    pass


@dataclass
class Proc:
    name: str
    proc: subprocess.Popen[bytes]
    log: Path

    def tail(self, lines: int = 40) -> str:
        text = self.log.read_text(errors="replace").splitlines()
        return f"--- {self.name} (pid {self.proc.pid}, exit {self.proc.poll()}):\n" + "\n".join(
            text[-lines:]
        )


@dataclass
class LocalCompose:
    """Services started in dependency order, stopped newest first (SIGTERM, as docker stop)."""

    compose: dict[str, Any]
    image: Image
    world: LocalWorld
    marker: str = field(default_factory=lambda: uuid.uuid4().hex)
    procs: dict[str, Proc] = field(default_factory=dict)
    exit_codes: dict[str, int] = field(default_factory=dict)
    health: dict[str, str] = field(default_factory=dict)

    @property
    def services(self) -> dict[str, Any]:
        return self.compose["services"]

    def argv(self, name: str) -> list[str]:
        spec = self.services[name]
        if not is_ours(spec):
            return zenoh_router_argv(name, spec, self.world)
        return local_executable(self.world.argv(container_argv(spec, self.image), name))

    def env(self, name: str) -> dict[str, str]:
        return local_env(name, self.services[name], self.image, self.world, self.marker)

    def start(self, name: str) -> Proc:
        for dep, condition in depends_on(self.services[name]).items():
            self._wait_for(dep, condition)
        log = self.world.root / "logs" / f"{name}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        argv = self.argv(name)
        with open(log, "wb") as fh:
            proc = subprocess.Popen(
                argv,
                stdin=subprocess.DEVNULL,
                stdout=fh,
                stderr=subprocess.STDOUT,
                env=self.env(name),
                cwd=self.world.root,
                start_new_session=True,
            )
        self.procs[name] = Proc(name, proc, log)
        return self.procs[name]

    def _wait_for(self, dep: str, condition: str) -> None:
        if dep in self.health:
            return
        if dep not in self.procs:
            raise ComposeRunError(f"{dep} was not started before its dependants")
        if condition == "service_healthy":
            self.health[dep] = self.wait_healthy(dep)
        elif condition != "service_started":
            raise ComposeRunError(f"depends_on condition {condition!r} has no local stand-in")

    def run_healthcheck(self, name: str) -> subprocess.CompletedProcess[str]:
        spec = self.services[name]
        argv = local_executable(self.world.argv(health_argv(spec), name))
        timeout = parse_duration(spec["healthcheck"].get("timeout", "30s"))
        return subprocess.run(
            argv, env=self.env(name), capture_output=True, text=True, timeout=timeout, check=False
        )

    def wait_healthy(self, name: str) -> str:
        """Run the healthcheck as Docker would until it passes (start period + retries)."""
        hc = self.services[name].get("healthcheck")
        if hc is None:
            raise ComposeRunError(f"{name}: service_healthy needs a healthcheck")
        interval = parse_duration(hc.get("interval", "30s"))
        pause = parse_duration(hc.get("start_interval", "5s"))
        budget = parse_duration(hc.get("start_period", "0s")) + interval * int(hc.get("retries", 3))
        deadline = time.monotonic() + budget
        while True:
            proc = self.procs[name]
            if proc.proc.poll() is not None:
                raise ComposeRunError(f"{name} exited while starting\n{self.logs()}")
            try:
                result = self.run_healthcheck(name)
            except subprocess.TimeoutExpired:
                result = None
            if result is not None and result.returncode == 0:
                return result.stdout.strip()
            if time.monotonic() > deadline:
                said = "timed out" if result is None else (result.stdout + result.stderr).strip()
                raise ComposeRunError(f"{name} never became healthy: {said}\n{self.logs()}")
            time.sleep(pause)

    def check_alive(self) -> None:
        for p in self.procs.values():
            if p.name != EXIT_SERVICE and p.proc.poll() is not None:
                raise ComposeRunError(f"{p.name} exited early\n{self.logs()}")

    def logs(self) -> str:
        return "\n".join(p.tail() for p in self.procs.values())

    def stop_all(self) -> dict[str, int]:
        """SIGTERM each running service, newest first; SIGKILL after its stop_grace_period."""
        for p in reversed(list(self.procs.values())):
            if p.proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(p.proc.pid, signal.SIGTERM)
                try:
                    p.proc.wait(parse_duration(self.services[p.name].get("stop_grace_period", 10)))
                except subprocess.TimeoutExpired:
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(p.proc.pid, signal.SIGKILL)
                    p.proc.wait()
                    self.exit_codes[p.name] = -signal.SIGKILL
                    continue
            self.exit_codes.setdefault(p.name, p.proc.returncode)
        return self.exit_codes


def leftover_pids(marker: str) -> list[int]:
    """PIDs of live processes (any descendant) whose environment carries ``marker``."""
    needle = f"{MARKER_ENV}={marker}".encode()
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        with contextlib.suppress(OSError):
            if needle in (entry / "environ").read_bytes():
                state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
                if state != "Z":
                    found.append(int(entry.name))
    return found


@contextlib.contextmanager
def local_compose(compose: dict[str, Any], root: Path) -> Iterator[LocalCompose]:
    image = read_image()
    run = LocalCompose(compose, image, build_world(compose, image, root))
    finished = False
    try:
        yield run
        finished = True
    finally:
        run.stop_all()
        left = leftover_pids(run.marker)
        for pid in left:  # started by this run (they carry its marker): end them by pid
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        if finished:
            assert left == [], f"processes left behind: {left}"
