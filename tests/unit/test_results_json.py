"""results.json is strict JSON: a metric that never happened is null, never a bare NaN."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

from ftcap_hil.config.scenario import load_scenario
from ftcap_hil.core.status import Mode
from ftcap_hil.report.records import json_ready, write_results
from ftcap_hil.report.summary import flight_summary_lines
from ftcap_hil.runtime.offline import run_modes


def _strict(text: str) -> object:
    def refuse(name: str) -> None:
        raise ValueError(f"not JSON: {name}")

    return json.loads(text, parse_constant=refuse)


def test_non_finite_floats_become_null_at_every_depth() -> None:
    obj = {"a": math.nan, "b": [1.0, math.inf, (-math.inf, 2)], "c": {"d": math.nan}, "e": "x"}
    assert json_ready(obj) == {"a": None, "b": [1.0, None, [None, 2]], "c": {"d": None}, "e": "x"}


def test_results_json_of_a_run_is_strict_and_its_summary_reads_it(tmp_path: Path) -> None:
    sc = replace(load_scenario("paper-4.2-ex1"), duration_s=14.0)
    records = run_modes(sc, [Mode.NONE, Mode.CAP])
    # a ground station's record carries such entries (a statistic of no samples); the
    # demo's results.json held a bare NaN this way
    records["cap"].meta["latency_ms_p99"] = math.nan
    res = write_results(records, tmp_path)
    assert math.isnan(res["modes"]["cap"]["latency_ms_p99"])  # returned as computed
    back = _strict((tmp_path / "results.json").read_text())
    assert isinstance(back, dict)
    assert back["modes"]["cap"]["latency_ms_p99"] is None
    assert flight_summary_lines(back)  # null read back as "-", not a format error
