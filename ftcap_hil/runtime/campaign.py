"""Running a campaign: every run a task on ``dask.distributed``, results appended as they come.

A campaign is a list of :class:`RunTask`; the tasks of one *case* (scenario x seed x fault
draw) share its fault-free ``none`` run, which is computed once and handed to the others as
a Dask future (its positions and commands only, not the whole record). A run that raises is
returned as a failed row with its traceback; a task that Dask itself loses (a worker killed
after the retries) is recorded the same way. Each finished row is appended to
``DIR/runs.jsonl`` at once, so an interrupted campaign resumes by skipping the keys it has.

Execution: an embedded ``LocalCluster`` (processes, one thread each, scheduler and workers
on 127.0.0.1, no dashboard) or, with a scheduler address, an existing cluster used as it is.
Dask is imported inside the functions that need it, so importing this module is cheap.
"""

from __future__ import annotations

import json
import logging
import math
import os
import socket
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ftcap_hil.config.campaign import MetricParams
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.scenario import Scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.report.campaign_metrics import Reference, reference_of, run_metrics

if TYPE_CHECKING:
    from distributed import Client, Future

log = logging.getLogger(__name__)
RESULTS = "runs.jsonl"
RETRIES = 2  # a task whose worker died is tried again this often before it is recorded failed


@dataclass(frozen=True)
class RunTask:
    """One run: ``scenario`` (with every override applied) in ``mode``.

    key: unique in the campaign, ``<case>/<variant>``; digest: hash of what runs (the
    scenario document and the mode), so a resumed campaign never reuses a stale result.
    fault_kinds: the generator's label per thruster (0-based), for the per-kind tables.
    """

    key: str
    digest: str
    case: str
    variant: str
    mode: Mode
    scenario: Scenario
    label: str
    seed: int
    healthy: bool
    kind: str
    length_m: float
    replay: str
    fault_kinds: tuple[tuple[int, str], ...] = ()

    @property
    def is_reference(self) -> bool:
        return self.mode is Mode.NONE

    def head(self) -> dict[str, Any]:
        """The identifying columns of this task's result row."""
        return {
            "key": self.key,
            "digest": self.digest,
            "case": self.case,
            "scenario": self.label,
            "seed": self.seed,
            "healthy": self.healthy,
            "kind": self.kind,
            "variant": self.variant,
            "mode": self.mode.value,
            "duration_s": self.scenario.duration_s,
            "dt_s": self.scenario.dt_s,
            "length_m": self.length_m,
            "replay": self.replay,
        }


@dataclass(frozen=True)
class CampaignPlan:
    name: str
    tasks: tuple[RunTask, ...]
    params: MetricParams = field(default_factory=MetricParams)


@dataclass(frozen=True)
class ReferenceResult:
    row: dict[str, Any]
    reference: Reference | None


def _worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _failed(task: RunTask, error: str, started: float) -> dict[str, Any]:
    return {
        **task.head(),
        "status": "failed",
        "error": error,
        "wall_s": time.perf_counter() - started,
        "worker": _worker_name(),
    }


def _simulate(task: RunTask, ref: Reference | None, params: MetricParams) -> tuple[Any, dict]:
    from ftcap_hil.runtime.offline import run_mode

    started = time.perf_counter()
    rec = run_mode(task.scenario, task.mode)
    row = {**task.head(), "status": "ok", "error": None}
    row.update(run_metrics(rec, ref, params, dict(task.fault_kinds)))
    row["wall_s"], row["worker"] = time.perf_counter() - started, _worker_name()
    return rec, row


def execute_reference(task: RunTask, params: MetricParams) -> ReferenceResult:
    """The fault-free run of a case (a Dask task): its row and what the others need."""
    started = time.perf_counter()
    try:
        rec, row = _simulate(task, None, params)
        return ReferenceResult(row, reference_of(rec))
    except Exception:
        return ReferenceResult(_failed(task, traceback.format_exc(), started), None)


def execute_run(task: RunTask, ref: ReferenceResult, params: MetricParams) -> dict[str, Any]:
    """One run of a case against its reference (a Dask task); never raises."""
    started = time.perf_counter()
    if ref.reference is None:
        return _failed(task, f"reference run {ref.row['key']} failed", started)
    try:
        return _simulate(task, ref.reference, params)[1]
    except Exception:
        return _failed(task, traceback.format_exc(), started)


class ResultStore:
    """``DIR/runs.jsonl``: one JSON object per finished run, appended and flushed."""

    def __init__(self, out_dir: Path) -> None:
        self.path = out_dir / RESULTS
        out_dir.mkdir(parents=True, exist_ok=True)

    def rows(self) -> list[dict[str, Any]]:
        """Every complete line (a line cut off by an interruption is skipped)."""
        if not self.path.exists():
            return []
        out = []
        for n, line in enumerate(self.path.read_text().splitlines(), 1):
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                log.warning("%s:%d: incomplete line skipped (interrupted write)", self.path, n)
        return out

    def done(self, tasks: Iterable[RunTask], retry_failed: bool) -> set[str]:
        """Keys of ``tasks`` already recorded; a key recorded with another digest is an error."""
        by_key = {t.key: t for t in tasks}
        done = set()
        for row in self.rows():
            task = by_key.get(row.get("key", ""))
            if task is None:
                continue
            if row.get("digest") != task.digest:
                raise ConfigError(
                    f"{self.path}: run {task.key} was recorded for a different campaign "
                    "(its scenario or mode changed): use another --out folder"
                )
            if row.get("status") == "ok" or not retry_failed:
                done.add(task.key)
        return done

    def drop_partial_line(self) -> None:
        """Cut a last line without its newline (a write stopped midway) so that appended
        rows start on a line of their own."""
        if not self.path.exists():
            return
        data = self.path.read_bytes()
        if data and not data.endswith(b"\n"):
            log.warning("%s: dropping an incomplete last line (interrupted write)", self.path)
            with open(self.path, "r+b") as fh:
                fh.truncate(data.rfind(b"\n") + 1)

    def append(self, row: dict[str, Any]) -> None:
        with open(self.path, "a") as fh:
            fh.write(json.dumps(row, allow_nan=False) + "\n")
            fh.flush()


def embedded_cluster(workers: int | None) -> Any:
    """A LocalCluster on this machine: processes, one thread each, all on 127.0.0.1."""
    from distributed import LocalCluster

    return LocalCluster(
        n_workers=workers or os.cpu_count() or 1,
        processes=True,
        threads_per_worker=1,
        host="127.0.0.1",
        scheduler_port=0,
        dashboard_address=None,
        worker_dashboard_address=None,
        protocol="tcp",
    )


def _submit(client: Client, plan: CampaignPlan, todo: set[str]) -> dict[Future, RunTask]:
    """Futures for the runs in ``todo``; each case's reference is submitted when one of
    its runs is missing, even if its own row is already recorded."""
    futures: dict[Future, RunTask] = {}
    refs: dict[str, Future] = {}
    needed = {t.case for t in plan.tasks if t.key in todo}
    for task in plan.tasks:
        if task.is_reference and task.case in needed:
            ref = client.submit(
                execute_reference,
                task,
                plan.params,
                key=f"ref:{task.key}:{task.digest}",
                retries=RETRIES,
                priority=10,
            )
            refs[task.case] = ref
            if task.key in todo:
                futures[ref] = task
    for task in plan.tasks:
        if not task.is_reference and task.key in todo:
            fut = client.submit(
                execute_run,
                task,
                refs[task.case],
                plan.params,
                key=f"run:{task.key}:{task.digest}",
                retries=RETRIES,
            )
            futures[fut] = task
    return futures


def _row_of(fut: Future, task: RunTask) -> dict[str, Any]:
    if fut.status == "error":
        return _failed(task, f"dask: {fut.exception()!r}", time.perf_counter())
    if fut.status != "finished":
        return _failed(task, f"dask: task {fut.status}", time.perf_counter())
    result = fut.result()
    return result.row if isinstance(result, ReferenceResult) else result


def _completed(client: Client, futures: dict[Future, RunTask]) -> Iterator[dict[str, Any]]:
    from distributed import as_completed

    for fut in as_completed(list(futures)):
        yield _row_of(fut, futures.pop(fut))
        fut.release()


class ProgressLines:
    """The campaign's progress where no progress bar can be drawn (a log, a pipe, CI): a
    line on ``stream`` every ``every_s`` of wall time and at the end: runs done of the
    total, runs/s since the start, and the time left at that rate."""

    def __init__(self, total: int, every_s: float = 10.0, stream: Any = None) -> None:
        self.total, self.every_s, self.done = total, every_s, 0
        self.stream = sys.stderr if stream is None else stream
        self._t0 = self._last = time.monotonic()

    def update(self, n: int = 1) -> None:
        """``n`` more runs done; a line if ``every_s`` passed since the last."""
        self.done += n
        now = time.monotonic()
        if now - self._last >= self.every_s or self.done == self.total:
            self._last = now
            self.stream.write(self.text(now - self._t0) + "\n")
            self.stream.flush()

    def text(self, elapsed_s: float) -> str:
        """``campaign: 12/400 runs (3 %), 0.41 runs/s, about 946 s left``."""
        rate = self.done / elapsed_s if elapsed_s > 0 else 0.0
        left = (self.total - self.done) / rate if rate > 0 else math.inf
        eta = "-" if math.isinf(left) else f"about {left:.0f} s left"
        pct = 100.0 * self.done / self.total if self.total else 100.0
        return f"campaign: {self.done}/{self.total} runs ({pct:.0f} %), {rate:.2f} runs/s, {eta}"

    def __enter__(self) -> ProgressLines:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


def _progress(total: int, quiet: bool) -> Any:
    """A progress bar (runs, runs/s, ETA) on a terminal, :class:`ProgressLines` elsewhere,
    nothing when ``quiet``."""
    if not quiet and not sys.stderr.isatty():
        return ProgressLines(total)
    from tqdm import tqdm

    return tqdm(total=total, unit="run", file=sys.stderr, disable=quiet)


def run_campaign(
    plan: CampaignPlan,
    out_dir: Path,
    scheduler: str | None = None,
    workers: int | None = None,
    retry_failed: bool = False,
    quiet: bool = False,
    on_row: Callable[[dict[str, Any]], None] | None = None,
    dask_logs: bool = False,
) -> list[dict[str, Any]]:
    """Run what ``out_dir`` does not hold yet; returns the rows written by this call.
    dask_logs: keep the scheduler's INFO lines (else warnings only)."""
    from distributed import Client

    if not dask_logs:  # set after the import: dask's own logging config sets INFO on import
        logging.getLogger("distributed").setLevel(logging.WARNING)

    store = ResultStore(out_dir)
    store.drop_partial_line()
    done = store.done(plan.tasks, retry_failed)
    todo = {t.key for t in plan.tasks} - done
    written: list[dict[str, Any]] = []
    if not todo:
        return written
    cluster = None if scheduler else embedded_cluster(workers)
    try:
        with Client(scheduler or cluster) as client, _progress(len(todo), quiet) as bar:
            for row in _completed(client, _submit(client, plan, todo)):
                store.append(row)
                written.append(row)
                bar.update(1)
                if on_row is not None:
                    on_row(row)
    finally:
        if cluster is not None:
            cluster.close()
    return written
