"""``docker compose -f docker/compose.yaml up --exit-code-from gcs``, run without Docker.

CI has no Docker engine, so the test runs what the compose file says instead of the
containers: every service built from docker/Dockerfile as the image's ENTRYPOINT (read from
the Dockerfile) + the service's ``command``, with the image's ENV, the service's
``environment`` and the files it mounts; compose's ``${VAR:-default}`` interpolation (from
this process's environment, as compose reads the shell's) and its splitting of string
commands applied; the eclipse/zenoh router replaced by a router session of the same Zenoh
release from the same mounted file; ``service_healthy`` waited for by running the service's
own healthcheck. Container names and ports are mapped onto 127.0.0.1 and free ports, the same
way in arguments, mounted files, health checks and published ports (compose_local.py).

It checks that the mission completes (exit 0) with every fault identified in results.json,
that a host GCS on the published MAVLink ports hears the vessel and the allocator, that the
allocator is still healthy afterwards, that SIGTERM (``docker stop``) ends every service with
exit 0 and that no process is left. A CLI flag, a config key or a file that does not exist
makes a process exit or the mapping fail, so the test fails with that process's log (the
tests at the end prove it); ``--set`` keys the product would silently ignore are checked
against the shipped configs. Static checks are in test_compose_static.py.

The flight is the default mission (paper-4.2-ex1-short) to 75 s, through its second onset
(``FTCAP_GCS_ARGS="--duration 75"``, set the way it would shorten ``docker compose up``): the
same flight also carries the live claims about that onset (tests/support/second_onset.py:
healthy thrusters never flagged, the dead one out), which an e2e demo flight of the same
mission to 75 s used to make on its own.
"""

from __future__ import annotations

import json
import math
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from tests.docker.compose_files import (
    COMPOSE,
    COMPOSE_VCAN,
    EXIT_SERVICE,
    argv_of,
    container_argv,
    gcs_mission,
    is_ours,
    load_compose,
    read_image,
    start_order,
    unknown_set_keys,
)
from tests.docker.compose_local import (
    LOCAL,
    ComposeRunError,
    LocalCompose,
    free_port,
    health_argv,
    local_compose,
    local_executable,
)
from tests.support.records import float_rows
from tests.support.second_onset import check_second_onset

FLIGHT_S = 75.0  # through the second onset at 45 s (module docstring)


def mission_budget_s(argv: list[str]) -> float:
    """Seconds the ground station should need: --duration, else the mission's own."""
    from ftcap_hil.config.mission import load_mission

    if "--duration" in argv:
        return float(argv[argv.index("--duration") + 1])
    return load_mission(argv[argv.index("--mission") + 1]).duration_s


def check_published_mavlink(run: LocalCompose) -> dict[str, float]:
    """A host GCS (MAVProxy, QGroundControl) on the published ports hears both components."""
    from bridges.mavlink.config import MavlinkEndpoint
    from bridges.mavlink.gcs import MavlinkGcsLink

    published = [
        int(str(p).split(":")[-1].split("/")[0])
        for spec in run.services.values()
        for p in spec.get("ports", [])
    ]
    peers = tuple(f"{LOCAL}:{run.world.ports[p]}" for p in published)
    me = free_port(set(run.world.ports.values()))
    endpoint = MavlinkEndpoint(f"udpin:{LOCAL}:{me}", 255, 250, peers)
    with MavlinkGcsLink(endpoint) as link:
        assert link.wait_heartbeat(link.vessel_ids, 10.0), (
            "no vessel HEARTBEAT on its published port"
        )
        assert link.wait_heartbeat(link.allocator_ids, 10.0), "no allocator HEARTBEAT published"
        return link.fetch_params(link.allocator_ids, timeout_s=5.0)


def check_results(out: Path, mission: str) -> dict[str, Any]:
    """results.json of a finished mission, with every fault identified by F-TCAP."""
    results = json.loads((out / "results.json").read_text())
    assert results["schema"] == 1
    assert set(results["modes"]) == {"ftcap"}, "the allocator's default mode flew"
    run = results["modes"]["ftcap"]
    assert run["mission"] == mission and run["bounded"] is True
    assert run["injections"], "the mission injected no fault"
    assert all(i["result"] == "ACCEPTED" for i in run["injections"]), run["injections"]
    starts = [p[0] for p in results["phases"]]
    assert [p["start"] for p in run["phases"]] == starts and len(starts) >= 2
    for phase in run["phases"]:
        where = f"phase [{phase['start']}, {phase['end']})"
        errors = phase["delta_error_final"]
        assert all(e is not None and math.isfinite(e) and e <= 0.05 for e in errors), (
            where,
            errors,
        )
        assert all(t is not None for t in phase["delta_convergence_time"]), where
    assert (out / "ftcap" / "timeseries.csv").is_file()
    assert sorted(out.glob("*.png")), "no plots"
    return results


@pytest.mark.e2e
@pytest.mark.timeout(900)
def test_compose_up_flies_the_mission_as_local_processes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`docker compose -f docker/compose.yaml up --exit-code-from gcs`, without Docker."""
    monkeypatch.setenv("FTCAP_GCS_ARGS", f"--duration {FLIGHT_S:g}")
    compose = load_compose(COMPOSE)
    image = read_image()
    mission, gcs_argv = gcs_mission(compose, image)
    for name, spec in compose["services"].items():
        if is_ours(spec):
            assert unknown_set_keys(container_argv(spec, image)) == [], name
    budget = mission_budget_s(gcs_argv) + 120.0
    with local_compose(compose, tmp_path) as run:
        for name in start_order(run.services):
            run.start(name)
        run.check_alive()
        params = check_published_mavlink(run)
        assert params["FTC_MODE"] == 2  # ftcap
        gcs = run.procs[EXIT_SERVICE]
        deadline = time.monotonic() + budget
        while gcs.proc.poll() is None:
            run.check_alive()
            if time.monotonic() > deadline:
                raise ComposeRunError(f"the ground station overran {budget:.0f} s\n{run.logs()}")
            time.sleep(0.5)
        assert gcs.proc.returncode == 0, run.logs()
        after = run.run_healthcheck("allocator")  # still healthy after the flight
        assert after.returncode == 0, after.stdout + after.stderr
        codes = run.stop_all()
    assert codes == dict.fromkeys(codes, 0), f"not a clean stop on SIGTERM: {codes}\n{run.logs()}"
    assert "allocator: mode ftcap" in run.health["allocator"]
    gcs_log = gcs.log.read_text()
    assert "inject WEAK on thruster 1 (value 0.9): ACCEPTED" in gcs_log
    out = run.world.mounts[EXIT_SERVICE]["/out"]
    check_results(out, mission)
    allocator_log = run.procs["allocator"].log.read_text(errors="replace")
    found = check_second_onset(allocator_log, float_rows(out / "ftcap" / "timeseries.csv"))
    print(f"\nthruster 3 found dead {found:.1f} s after the second onset")


# ---------------------------------------------------------------- the harness catches drift


def _with_command(compose: dict[str, Any], service: str, extra: list[str]) -> dict[str, Any]:
    spec = compose["services"][service]
    spec["command"] = argv_of(spec["command"]) + extra
    return compose


@pytest.mark.e2e
@pytest.mark.timeout(120)
def test_a_flag_that_does_not_exist_fails_the_run(tmp_path: Path) -> None:
    compose = _with_command(load_compose(COMPOSE), "allocator", ["--no-such-flag"])
    with pytest.raises(ComposeRunError, match="allocator exited while starting"):
        with local_compose(compose, tmp_path) as run:
            for name in start_order(run.services):
                run.start(name)
    assert (
        "unrecognized arguments: --no-such-flag"
        in (tmp_path / "logs" / "allocator.log").read_text()
    )


@pytest.mark.e2e
@pytest.mark.timeout(120)
def test_a_config_file_that_does_not_exist_fails_the_run(tmp_path: Path) -> None:
    compose = _with_command(
        load_compose(COMPOSE), "allocator", ["--set", "zenoh.config=/etc/ftcap/zenoh/nope.json5"]
    )
    with pytest.raises(ComposeRunError, match="allocator exited while starting"):
        with local_compose(compose, tmp_path) as run:
            for name in start_order(run.services):
                run.start(name)
    assert "nope" in (tmp_path / "logs" / "allocator.log").read_text()


# ---------------------------------------------------------------- compose.vcan.yaml


@pytest.mark.e2e
@pytest.mark.timeout(120)
@pytest.mark.parametrize("service", ["allocator", "vessel"])
def test_vcan_override_gets_as_far_as_opening_vcan0(service: str, tmp_path: Path) -> None:
    """With no vcan0 here, the override's commands fail at the CAN port and nowhere earlier:
    every flag and key before it was accepted (a vcan host would bind the shipped fixed ports:
    the SocketCAN runs belong to tests/vcan)."""
    if Path("/sys/class/net/vcan0").exists():
        pytest.skip("vcan0 is up here: the command would run with the shipped fixed ports")
    spec = load_compose(COMPOSE, COMPOSE_VCAN)["services"][service]
    assert spec["network_mode"] == "host"
    argv = local_executable(container_argv(spec, read_image()))
    done = subprocess.run(
        argv, capture_output=True, text=True, timeout=60, cwd=tmp_path, check=False
    )
    assert done.returncode in (1, 2), done.stdout + done.stderr
    said = done.stdout + done.stderr
    assert "cannot open CAN bus interface='socketcan' channel='vcan0'" in said, said


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_vcan_override_healthcheck_names_a_shipped_config(tmp_path: Path) -> None:
    """The override's allocator check uses the shipped `gcs` client config: with no allocator
    running it must say unhealthy (exit 1), not fail on its arguments (exit 2)."""
    spec = load_compose(COMPOSE, COMPOSE_VCAN)["services"]["allocator"]
    image = read_image()
    argv = local_executable(health_argv(spec))
    script = str(image.copies["/opt/ftcap/healthcheck.py"])
    argv = [script if a == "/opt/ftcap/healthcheck.py" else a for a in argv]
    done = subprocess.run(
        argv, capture_output=True, text=True, timeout=30, cwd=tmp_path, check=False
    )
    assert done.returncode == 1 and done.stdout.startswith("unhealthy: allocator:"), (
        done.stdout + done.stderr
    )
