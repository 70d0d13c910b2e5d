"""The README and docs/ hold together: every relative link resolves (file and heading), every
``docs/PAGE.md#anchor`` or ``docs/PAGE.md, "Heading"`` that code, data files or docs cite
names a real heading, and the README stays a five-minute read that lists every command."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from ftcap_hil.apps.cli import COMMANDS

ROOT = Path(__file__).resolve().parents[2]
PAGES = sorted(
    [ROOT / "README.md", *(ROOT / "docs").glob("*.md"), *(ROOT / "tests").glob("*/README.md")]
    + [p for p in ROOT.glob("*/README.md") if not p.parent.name.startswith(".")]
)
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
NAMED = re.compile(r"\bdocs/[\w.-]+\.md")
CITED = re.compile(r"(docs/[\w.-]+\.md)(?:#([\w-]+)|,? \"([^\"]+)\")")
CITING = ("ftcap_hil", "sim", "bridges", "docs", "bench", "docker", "scripts")


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def prose(text: str) -> list[str]:
    """The lines of a Markdown page outside fenced code blocks, inline code removed."""
    lines, fenced = [], False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif not fenced:
            lines.append(re.sub(r"`[^`]*`", "", line))
    return lines


def anchors(page: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for line in prose(page.read_text()):
        if m := re.match(r"^#{1,6} (.+)$", line):
            base = slug(m.group(1))
            n = seen.get(base, 0)
            seen[base] = n + 1
            out.add(base if n == 0 else f"{base}-{n}")
    return out


def test_the_pages_are_found() -> None:
    names = {str(p.relative_to(ROOT)) for p in PAGES}
    assert {"README.md", "docs/hil.md", "docs/scenarios.md", "tests/vcan/README.md"} <= names


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page: Path) -> None:
    broken = []
    for line in prose(page.read_text()):
        for target in LINK.findall(line):
            if re.match(r"^[a-z]+:", target):
                continue  # http:, https:, mailto:
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            if not dest.exists():
                broken.append(f"{target}: no such file")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                broken.append(f"{target}: no heading #{anchor}")
    assert broken == []


def citing_files() -> list[Path]:
    files = [ROOT / "README.md"]
    for folder in CITING:
        files += [p for p in (ROOT / folder).rglob("*") if p.suffix in (".py", ".toml", ".md")]
    return files


def cited_sections() -> list[tuple[str, str, str]]:
    """(citing file, page, anchor) for every section of a page in docs/ cited by name."""
    out = []
    for path in citing_files():
        for page, anchor, heading in CITED.findall(path.read_text()):
            out.append((str(path.relative_to(ROOT)), page, anchor or slug(heading)))
    return out


def test_every_cited_section_exists() -> None:
    cited = cited_sections()
    assert ("ftcap_hil/config/realistic.py", "docs/scenarios.md", "realistic-scenarios") in cited
    missing = [c for c in cited if c[2] not in anchors(ROOT / c[1])]
    assert missing == []


def test_every_cited_page_exists() -> None:
    named = {
        (str(p.relative_to(ROOT)), n) for p in citing_files() for n in NAMED.findall(p.read_text())
    }
    assert ("README.md", "docs/hil.md") in named
    assert [c for c in sorted(named) if not (ROOT / c[1]).is_file()] == []


def test_the_link_checker_sees_a_broken_link(tmp_path: Path) -> None:
    (tmp_path / "a.md").write_text("# Top\n\n## Real scenarios\n\nsee [b](b.md) and [c](#top)\n")
    assert anchors(tmp_path / "a.md") == {"top", "real-scenarios"}
    assert slug("Realistic scenarios") == "realistic-scenarios"
    assert (
        slug("paper-4.2-ex1 (rk4 truth, euler inversion)")
        == "paper-42-ex1-rk4-truth-euler-inversion"
    )
    assert LINK.findall("see [b](b.md) and [c](#top)") == ["b.md", "#top"]


def test_the_readme_is_a_five_minute_read() -> None:
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 150
    for name in COMMANDS:
        assert f"`ftcap-hil {name}" in text, name
    # .ci/run reads the first two lines indented by four spaces: the install and the tests
    commands = [line[4:] for line in text.splitlines() if re.match(r"^    \S", line)][:2]
    assert commands == [
        "bash scripts/install.sh && .venv/bin/ftcap-hil demo --out out/demo",
        "bash scripts/test.sh",
    ]


def test_the_docs_name_the_default_backend() -> None:
    from ftcap_hil.core.allocation.allocator import AllocatorConfig

    assert AllocatorConfig().backend == "daqp"
    for page in PAGES:
        assert "proxsuite (default)" not in page.read_text(), page
