"""``ftcap-hil campaign`` runs where the transport libraries cannot be imported: the shipped
smoke campaign on one embedded Dask worker, every process (the workers too) started with
pymavlink, zenoh, can and dronecan refused."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.no_transports import env_without_transports

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(300)]


def test_the_smoke_campaign_runs_without_the_transports(tmp_path: Path) -> None:
    env = env_without_transports(tmp_path / "refuse")
    out = tmp_path / "smoke"
    cmd = [sys.executable, "-m", "ftcap_hil", "campaign", "smoke", "--out", str(out)]
    cmd += ["--workers", "1", "--quiet", "--no-plots"]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=280, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "33 recorded, 0 failed" in done.stdout
    with open(out / "runs.csv", newline="") as fh:
        assert len(list(csv.DictReader(fh))) == 33
