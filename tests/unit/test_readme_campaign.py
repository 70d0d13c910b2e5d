"""The README's campaign table is the committed campaign's own output (issue 19): the block
between the headline markers in README.md equals the one in docs/results/sweeps/summary.md,
which `ftcap-hil campaign sweeps --out DIR` writes (docs/results/README.md says how it is
published)."""

from __future__ import annotations

from pathlib import Path

from ftcap_hil.report.campaign_report import HEADLINE_BEGIN, headline_block

ROOT = Path(__file__).resolve().parents[2]
SUMMARY = ROOT / "docs" / "results" / "sweeps" / "summary.md"


def test_the_readme_carries_the_committed_campaigns_headline() -> None:
    readme = (ROOT / "README.md").read_text()
    summary = SUMMARY.read_text()
    assert readme.count(HEADLINE_BEGIN) == 1
    assert headline_block(readme) == headline_block(summary)


def test_the_committed_summary_is_the_sweeps_campaigns_whole_run() -> None:
    summary = SUMMARY.read_text()
    assert summary.startswith("# Campaign sweeps\n")
    assert "2120 runs (2120 ok, 0 failed)" in summary
    assert "thresholds tuned on seeds 1001-1003 (disjoint)" in summary
    for png in ("sweep_map", "isolation_by_kind", "dev_cap_by_scenario"):
        assert (SUMMARY.parent / f"{png}.png").stat().st_size > 10_000, png
