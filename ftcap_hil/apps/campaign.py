"""Run a fault campaign: scenarios x seeds x modes as Dask tasks, then its statistics.

Writes DIR/runs.jsonl (one line per finished run, appended as runs complete: run the same
command again to resume an interrupted campaign), DIR/summary.md, DIR/runs.csv,
DIR/faults.csv (and .parquet when pyarrow is installed), distribution plots, and in
DIR/replay/ the scenario file of every run (runs.csv gives the `ftcap-hil simulate` command
that reproduces each). By default the runs go to an embedded Dask LocalCluster on
127.0.0.1 with one worker process per core; --scheduler uses an existing cluster.
Exit code 1 when some run failed (it is recorded, with its error, in the summary), 130
when interrupted (what finished is kept).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ftcap_hil.core.errors import ConfigError, ExitCode

if TYPE_CHECKING:
    from ftcap_hil.config.campaign import CampaignSpec
    from ftcap_hil.runtime.campaign import CampaignPlan


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("spec", help="a campaign TOML file or a shipped campaign (smoke, realistic)")
    p.add_argument("--out", type=Path, required=True, help="output folder (resumed if it exists)")
    p.add_argument(
        "--scheduler", metavar="tcp://HOST:PORT", help="an existing Dask scheduler to use"
    )
    p.add_argument(
        "--workers", type=int, help="embedded cluster: worker processes (default: cores)"
    )
    p.add_argument("--retry-failed", action="store_true", help="run recorded failures again")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _prepare(args: argparse.Namespace) -> tuple[CampaignSpec, CampaignPlan]:
    from ftcap_hil.config.campaign import load_campaign
    from ftcap_hil.runtime.campaign_plan import plan_campaign

    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers: need >= 1, got {args.workers}")
    if args.workers is not None and args.scheduler:
        raise ConfigError("--workers applies to the embedded cluster, not with --scheduler")
    spec = load_campaign(args.spec)
    out = args.out.resolve()
    plan, files = plan_campaign(spec, out)
    (out / "replay").mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (out / "replay" / name).write_text(text)
    return spec, plan


def run(args: argparse.Namespace) -> int:
    from ftcap_hil.report.campaign_report import write_report
    from ftcap_hil.runtime.campaign import ResultStore, run_campaign

    try:
        spec, plan = _prepare(args)
        started = time.perf_counter()
        written = run_campaign(
            plan,
            args.out.resolve(),
            args.scheduler,
            args.workers,
            args.retry_failed,
            args.quiet,
            dask_logs=bool(getattr(args, "verbose", 0)),
        )
    except ConfigError as e:
        print(f"ftcap-hil campaign: {e}", file=sys.stderr)
        return int(ExitCode.CONFIG)
    except KeyboardInterrupt:
        print(f"ftcap-hil campaign: interrupted; run it again to resume ({args.out})",
              file=sys.stderr)  # fmt: skip
        return int(ExitCode.INTERRUPTED)
    wall = time.perf_counter() - started
    keys = {t.key for t in plan.tasks}
    rows = [r for r in ResultStore(args.out.resolve()).rows() if r["key"] in keys]
    info = {
        "name": spec.name,
        "description": spec.description,
        "ran": len(written),
        "wall_s": wall,
        "tuning_seeds": list(spec.tuning_seeds),
        "scenarios": [s.label for s in spec.scenarios],
        "scheduler": args.scheduler
        or f"an embedded LocalCluster ({args.workers or 'one per core'} workers)",
    }
    paths = write_report(rows, plan.params, args.out, info, plots=not args.no_plots)
    from ftcap_hil.report.campaign_summary import latest

    failed = [r["key"] for r in latest(rows) if r["status"] != "ok"]
    print(f"{len(written)} runs now, {len(rows)} recorded, {len(failed)} failed, {wall:.1f} s")
    print("wrote " + ", ".join(str(p) for p in paths))
    return int(ExitCode.FAILURE) if failed else int(ExitCode.OK)
