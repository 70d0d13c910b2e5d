"""End-to-end on the real boat (issue 21, items 4 and 5): ``ftcap-hil demo --scenario`` flies
CyberShip II station keeping through the real processes (CAN hub, vessel running the
realistic truth, allocator told the same scenario, ground station) with a dead and with a
stuck starboard propeller, in real time and at twice real time, and is judged on the
vessel's clock against the offline run of the same case and seed: ratios and differences of
the same metrics (report/hil_compare.py), never wall-clock counts."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from ftcap_hil.config.scenario import SHIPPED, load_scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.report.hil_compare import live_metrics, offline_metrics, read_columns
from ftcap_hil.runtime.offline import run_mode
from tests.e2e.demo_support import ftcap_hil, reap, start, stderr_of

pytestmark = pytest.mark.e2e

SHIPPED_FILE = Path(__file__).resolve().parents[2] / SHIPPED.replace(".", "/")
DURATION_S = 45.0
ONSET_S = 20.0
FAULTS = {
    "dead": 'thruster = 2\ndelta = 0.0\ncause = "drive-dead"',
    "stuck": 'thruster = 2\nkind = "stuck"',
}


def case_file(tmp: Path, kind: str) -> Path:
    """cybership2-station, DURATION_S long, its starboard propeller ``kind`` at ONSET_S."""
    text = (SHIPPED_FILE / "cybership2-station.toml").read_text()
    text = text.replace("duration = 120.0", f"duration = {DURATION_S}")
    text = re.sub(
        r"\[\[fault\]\]\nfrom = 60.0\nthruster = 2\ndelta = 0.0\n",
        f"[[fault]]\nfrom = {ONSET_S}\n{FAULTS[kind]}\n",
        text,
    )
    assert f"from = {ONSET_S}" in text
    path = tmp / f"cs2-{kind}.toml"
    path.write_text(text)
    return path


# Known gap (docs/hil.md): at twice real time every wall-clock jitter counts double on the
# vessel's clock and can exceed the drives' diagnosis timing margin. Idle it agrees with
# offline (3 of 3 on c01502e); with the sweeps campaign's two workers beside it, once yes
# and once not (5 false alarms, isolation 4.3 s against 0.4 s). Not strict: a pass must not
# fail the suite; the fix belongs to the vessel's clock (issue 30), not to this tolerance.
FASTER_UNDER_LOAD = pytest.mark.xfail(
    strict=False, reason="x2 under load: jitter doubled on the sim clock (docs/hil.md)"
)


# Not the same fault live and offline: a frozen shaft holds the speed the onset lands on,
# and the starboard propeller swings from -1.3 to +1.75 N within 0.2 s about it, so live
# (another command sample at the onset) and offline (-0.91 N) fly different faults. Idle, at
# 966af72: live deviation 9.7-17.1 mm against offline's 8.0 (over the 5 mm in 3 of 11
# flights; 1 of 2 at 18f7c59), isolation 1.3-2.0 s against 1.3 (over the 0.7 s once).
# Not strict: the fix is a held value the scenario gives (issue 30), not a wider tolerance.
ONSET_DRAWN = pytest.mark.xfail(
    strict=False, reason="the frozen value is the onset's draw: live and offline differ"
)


@pytest.mark.parametrize(
    ("kind", "speed"),
    [
        ("dead", 1.0),
        pytest.param("dead", 2.0, marks=FASTER_UNDER_LOAD),
        pytest.param("stuck", 1.0, marks=ONSET_DRAWN),
    ],
)
@pytest.mark.timeout(420)
def test_live_flight_agrees_with_offline(tmp_path: Path, kind: str, speed: float) -> None:
    scenario = case_file(tmp_path, kind)
    out = tmp_path / "out"
    argv = ftcap_hil(
        "demo", "--scenario", str(scenario), "--speed", repr(speed), "--out", str(out),
        "--no-plots",
    )  # fmt: skip
    proc = start("demo", argv, tmp_path)
    try:
        code = proc.wait(DURATION_S / speed + 240)
        stdout, stderr = proc.output(), stderr_of(proc)
    finally:
        reap(proc, out)
    assert code == 0, stderr[-3000:]
    assert "verdict (ftcap live over MAVLink/CAN against offline" in stdout, stdout[-3000:]

    sc = load_scenario(scenario)
    none, offline = run_mode(sc, Mode.NONE), run_mode(sc, Mode.FTCAP)
    off = offline_metrics(offline, none)
    live = live_metrics(sc.faults, out / "vessel.csv", out / "ftcap" / "timeseries.csv", none)
    report = f"{kind} x{speed:g}: live {live}, offline {off}"
    print(report)

    # the vessel's clock covered the flight: sim time on its grid, no stall lost
    track = read_columns(out / "vessel.csv", ["time_s"])["time_s"]
    assert track[-1] >= DURATION_S - 1.0, report
    vessel_log = (out / "logs" / "vessel.log").read_text()
    lost = re.search(r"([0-9.]+) s lost to stalls", vessel_log)
    assert lost is not None and float(lost.group(1)) <= 0.5, vessel_log[-2000:]
    # the same fault found and isolated, as soon (one estimation period + 0.5 s, the issue's
    # target, plus the status path's 0.1 s decimation)
    assert off.isolation_s is not None and live.isolation_s is not None, report
    period = sc.estimation_period_s or sc.dt_s
    assert abs(live.isolation_s - off.isolation_s) <= period + 0.6, report
    # no false alarm live that offline does not have
    assert live.false_alarms <= off.false_alarms, report
    # the vessel held as close to the fault-free track as offline: within 25 % or 5 mm
    assert abs(live.deviation_rms_m - off.deviation_rms_m) <= max(
        0.25 * off.deviation_rms_m, 0.005
    ), report
