"""``ftcap-hil campaign`` end to end: a real Dask scheduler and worker as separate processes,
the embedded LocalCluster, failed runs, resuming, replaying a run, and the loopback rule.

One small campaign (the paper's vessel, 40 s runs, two seeds, a dead and an intermittent
fault, a variant that raises, one healthy run) is run once against ``dask scheduler`` /
``dask worker`` started here on 127.0.0.1 and once on the embedded cluster; the tests
compare what the two wrote. Every process started here is ended by its PID.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from ftcap_hil.runtime.processes import Child, Supervisor, free_ports

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(600)]

BIN = Path(sys.executable).parent
SPEC = """
[campaign]
name = "e2e"
description = "test campaign"
seeds = [1, 2]
modes = ["ftcap", "broken"]
duration = 40.0

[[scenario]]
source = "paper-4.2-ex1"
label = "paper"
faults = "random"

[variant.broken]          # raises inside the run: the filter's initial variance overflows
mode = "ftcap"
estimator = { initial_delta_std = 1e300 }

[faults]
kinds = ["dead", "intermittent"]
onset = [12.5, 16.0]
intermittent_on = [4.0, 6.0]
intermittent_off = [5.0, 8.0]

[healthy]
seeds = [1]
duration = 30.0
"""
# --no-dashboard leaves the HTTP server (health, metrics) listening on all interfaces, on
# :8787 for the scheduler and a random port for the worker: bind it to loopback too.
LOOPBACK_HTTP = ("--dashboard-address", "127.0.0.1:0")
VOLATILE = {"wall_s", "worker", "replay", "solve_us_median", "error"}
N_RUNS = 4 * 5 + 3  # 4 faulty cases x (none, cap, oracle, ftcap, broken) + healthy x 3


def _campaign(spec: Path, out: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(BIN / "ftcap-hil"), "campaign", str(spec), "--out", str(out), "--quiet", *args],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )


def _rows(out: Path) -> dict[str, dict[str, Any]]:
    lines = (out / "runs.jsonl").read_text().splitlines()
    return {r["key"]: r for r in map(json.loads, lines)}


def _stable(row: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in row.items() if k not in VOLATILE}


def _children(pid: int) -> list[int]:
    import psutil

    with contextlib.suppress(psutil.NoSuchProcess):
        return [p.pid for p in psutil.Process(pid).children(recursive=True)]
    return []


def _end(child: Child) -> None:
    """SIGTERM by PID (the worker's nanny then ends its worker), SIGKILL what is left."""
    pids = _children(child.pid)
    child.stop(signal.SIGTERM, 20.0)
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    child.close()


@pytest.fixture(scope="module")
def spec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("spec") / "e2e.toml"
    path.write_text(SPEC)
    return path


@pytest.fixture(scope="module")
def scheduler(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """``dask scheduler`` and ``dask worker`` processes on 127.0.0.1; the address."""
    (port,) = free_ports(1, 1)  # socket.SOCK_STREAM
    logs = tmp_path_factory.mktemp("dask")
    address = f"tcp://127.0.0.1:{port}"
    sup = Supervisor(logs)
    try:
        sup.start(
            "scheduler",
            [str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port),
             "--no-dashboard", *LOOPBACK_HTTP],
        )  # fmt: skip
        sup.start(
            "worker",
            [str(BIN / "dask"), "worker", address, "--host", "127.0.0.1", "--nworkers", "1",
             "--nthreads", "1", "--no-dashboard", *LOOPBACK_HTTP],
        )  # fmt: skip
        from distributed import Client

        with Client(address, timeout=60) as client:
            client.wait_for_workers(1, timeout=90)
        yield address
    finally:
        for child in reversed(sup.children):
            _end(child)


@pytest.fixture(scope="module")
def on_scheduler(spec: Path, scheduler: str, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("remote")
    done = _campaign(spec, out, "--scheduler", scheduler)
    assert done.returncode == 1, done.stdout + done.stderr  # the broken runs failed
    return out


@pytest.fixture(scope="module")
def embedded(spec: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("local")
    done = _campaign(spec, out, "--workers", "2")
    assert done.returncode == 1, done.stdout + done.stderr
    return out


def test_a_real_scheduler_and_the_embedded_cluster_give_the_same_rows(
    on_scheduler: Path, embedded: Path
) -> None:
    remote, local = _rows(on_scheduler), _rows(embedded)
    assert len(remote) == N_RUNS and set(remote) == set(local)
    for key in remote:
        assert _stable(remote[key]) == _stable(local[key]), key
    workers = {r["worker"] for r in local.values()}
    assert len(workers) == 2  # both embedded workers took runs
    ok = [r for r in remote.values() if r["status"] == "ok"]
    assert len(ok) == N_RUNS - 5
    dead = [f for r in ok if r["variant"] == "oracle" for f in r["faults"] if f["kind"] == "dead"]
    assert dead and all(f["detection_delay_s"] == 0.0 for f in dead)


def test_a_run_that_raises_is_a_recorded_failure(on_scheduler: Path) -> None:
    rows = _rows(on_scheduler)
    broken = [r for r in rows.values() if r["variant"] == "broken"]
    assert len(broken) == 5
    for row in broken:
        assert row["status"] == "failed" and "OverflowError" in row["error"], row["error"]
        assert "Traceback" in row["error"] and row["replay"].startswith("ftcap-hil simulate")
    summary = (on_scheduler / "summary.md").read_text()
    assert "## Failed runs" in summary and "paper/s1/dead/broken" in summary


def test_outputs_are_written(embedded: Path) -> None:
    pictures = ("distributions", "by_kind", "isolation_by_kind", "dev_cap_by_scenario", "sweep_map")
    for name in (
        "summary.md",
        "report.md",
        "runs.csv",
        "faults.csv",
        *[f"{p}.png" for p in pictures],
    ):
        assert (embedded / name).stat().st_size > 0, name
    header = (embedded / "runs.csv").read_text().splitlines()[0].split(",")
    assert {"key", "variant", "dev_ratio_oracle", "harm", "false_alarm_rate_per_h"} <= set(header)
    assert {"false_alarm_episodes_per_h", "removal_switches_per_h"} <= set(header)
    summary = (embedded / "summary.md").read_text()
    assert "| ftcap | dead |" in summary and "| ftcap | healthy |" in summary
    assert "## Where the method stops" in summary and "| ftcap | paper | dead |" in summary
    report = (embedded / "report.md").read_text()
    assert "(summary.md)" in report and all(f"({p}.png)" in report for p in pictures)


def test_an_interrupted_campaign_resumes_with_only_what_is_missing(
    spec: Path, embedded: Path, tmp_path: Path
) -> None:
    lines = (embedded / "runs.jsonl").read_text().splitlines()
    keep = [ln for ln in lines if '"status": "ok"' in ln][:9]
    # the 10th line was being written when the campaign was stopped: half a line
    (tmp_path / "runs.jsonl").write_text("\n".join(keep) + "\n" + keep[-1][:40])
    done = _campaign(spec, tmp_path, "--workers", "1")
    assert done.returncode == 1, done.stderr
    assert done.stdout.startswith(f"{N_RUNS - 9} runs now"), done.stdout
    resumed, reference = _rows(tmp_path), _rows(embedded)
    assert set(resumed) == set(reference)
    for key in reference:
        assert _stable(resumed[key]) == _stable(reference[key]), key
    again = _campaign(spec, tmp_path, "--workers", "1")
    assert again.stdout.startswith("0 runs now"), again.stdout  # nothing left to do
    retry = _campaign(spec, tmp_path, "--workers", "1", "--retry-failed")
    assert retry.stdout.startswith("5 runs now"), retry.stdout  # only the failed ones


def test_the_shipped_smoke_campaign(tmp_path: Path) -> None:
    """What CI runs of the campaign as shipped: every run succeeds, every kind reported."""
    done = _campaign(Path("smoke"), tmp_path, "--workers", "2")
    assert done.returncode == 0, done.stdout + done.stderr
    rows = _rows(tmp_path)
    assert len(rows) == 33 and all(r["status"] == "ok" for r in rows.values())
    oracle = [f for r in rows.values() if r["variant"] == "oracle" for f in r["faults"]]
    assert oracle and all(f["isolation_delay_s"] == 0.0 for f in oracle)
    summary = (tmp_path / "summary.md").read_text()
    for kind in ("dead", "partial", "intermittent", "healthy"):
        assert f"| ftcap | {kind} |" in summary, kind


def test_a_changed_campaign_does_not_reuse_stale_results(
    spec: Path, embedded: Path, tmp_path: Path
) -> None:
    changed = tmp_path / "changed.toml"
    changed.write_text(SPEC.replace("duration = 40.0", "duration = 41.0"))
    out = tmp_path / "out"
    out.mkdir()
    (out / "runs.jsonl").write_text((embedded / "runs.jsonl").read_text())
    done = _campaign(changed, out, "--workers", "1")
    assert done.returncode == 2 and "recorded for a different campaign" in done.stderr


def test_the_replay_command_reproduces_a_run(embedded: Path, tmp_path: Path) -> None:
    row = next(
        r for r in _rows(embedded).values() if r["variant"] == "ftcap" and r["kind"] == "dead"
    )
    cmd = row["replay"].split()
    assert cmd[:2] == ["ftcap-hil", "simulate"] and "--out" in cmd
    cmd[cmd.index("--out") + 1] = str(tmp_path / "replay")
    done = subprocess.run(
        [str(BIN / "ftcap-hil"), *cmd[1:], "--no-plots", "--quiet"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    res = json.loads((tmp_path / "replay" / "results.json").read_text())
    phases = res["modes"]["ftcap"]["phases"]
    assert len(phases) == len(row["phases"])
    for mine, theirs in zip(row["phases"], phases, strict=True):
        assert mine["deviation_rms"] == pytest.approx(theirs["deviation_rms"], rel=1e-12)
        assert mine["deviation_max"] == pytest.approx(theirs["deviation_max"], rel=1e-12)


def test_the_processes_listen_on_loopback_only(scheduler: str) -> None:
    """The embedded cluster, and the scheduler and worker started here (children too)."""
    import psutil
    from distributed import Client

    from ftcap_hil.runtime.campaign import embedded_cluster

    cluster = embedded_cluster(1)
    try:
        with Client(cluster) as client:
            client.wait_for_workers(1, timeout=60)
            info = client.scheduler_info()
            assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
            assert all(a.startswith("tcp://127.0.0.1:") for a in info["workers"])
            me = psutil.Process()
            listening = [
                c.laddr.ip
                for p in [me, *me.children(recursive=True)]
                for c in p.net_connections(kind="inet")
                if c.status == psutil.CONN_LISTEN
            ]
            assert listening and set(listening) <= {"127.0.0.1"}, listening
    finally:
        cluster.close()


def test_the_help_does_not_import_dask() -> None:
    code = (
        "import sys\nfrom ftcap_hil.apps.cli import build_parser\nbuild_parser()\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed')))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert done.stdout.strip() == "[]"
    helped = subprocess.run(
        [str(BIN / "ftcap-hil"), "campaign", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert helped.returncode == 0 and "--scheduler" in helped.stdout


def test_a_worker_that_dies_is_a_recorded_failure_and_the_campaign_goes_on(
    spec: Path, tmp_path: Path
) -> None:
    """A task whose worker process dies (here: it exits) is retried by Dask on a restarted
    worker and, when that dies too, recorded as failed; the next runs still complete."""
    import dask
    from distributed import Client

    from ftcap_hil.config.campaign import load_campaign
    from ftcap_hil.runtime.campaign import (
        ReferenceResult,
        _completed,
        embedded_cluster,
        execute_reference,
    )
    from ftcap_hil.runtime.campaign_plan import plan_campaign

    plan, _ = plan_campaign(load_campaign(spec), tmp_path)
    ref_task = plan.tasks[0]
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        cluster = embedded_cluster(1)
    try:
        with Client(cluster) as client:
            doomed = client.submit(os._exit, 3, key="doomed", retries=1)
            rows = list(_completed(client, {doomed: plan.tasks[1]}))
            assert rows[0]["status"] == "failed" and rows[0]["key"] == plan.tasks[1].key
            assert rows[0]["error"].startswith("dask: KilledWorker"), rows[0]["error"]
            after = client.submit(execute_reference, ref_task, plan.params, key="after")
            result = after.result(timeout=120)
            assert isinstance(result, ReferenceResult) and result.row["status"] == "ok"
    finally:
        cluster.close()
