"""The headline figures the README's results table and docs/results.md quote are those of a committed report:
each `mean ± error` verbatim, and each other figure of a README row as a number of the report its row
links (a figure retyped by hand, or left behind when a report was regenerated, fails here)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
LINK = re.compile(r"\]\(([^)\s]+)\)")
PLUS_MINUS = re.compile(r"(?<![\d.])\d+(?:\.\d+)? ± \d+(?:\.\d+)?(?![\d.])")
DECIMAL = re.compile(r"(?<![\d.])\d+\.\d+(?![\d.])")


def _reports(text: str, page: Path) -> list[Path]:
    """The committed reports `text` links (Markdown files under benchmarks/results/, or the lever comparisons
    `research/analyses/levers.py` writes under research/diary/reproduce_overcooked/levers/), relative to
    `page`."""
    out = []
    levers = ROOT / "research" / "diary" / "reproduce_overcooked" / "levers"
    written = (ROOT / "benchmarks" / "results", levers)
    for target in LINK.findall(text):
        path = (page.parent / target.split("#")[0]).resolve()
        if any(path.is_relative_to(folder) for folder in written) and path.suffix == ".md":
            out.append(path)
    return out


def _missing(text: str, reports: list[Path]) -> list[str]:
    """The figures of `text` that none of `reports` prints: a `mean ± error` verbatim, any other decimal as
    a number of its own (48.5 is not found in 148.5 or 48.51)."""
    printed = "\n".join(r.read_text() for r in reports)
    pairs = PLUS_MINUS.findall(text)
    missing = [p for p in pairs if p not in printed]
    rest = PLUS_MINUS.sub(" ", text)
    numbers = set(DECIMAL.findall(printed))
    return missing + [x for x in DECIMAL.findall(rest) if x not in numbers]


def _results_rows() -> list[str]:
    text = (ROOT / "README.md").read_text()
    section = text.split("\n## Results\n", 1)[1].split("\n## ", 1)[0]
    return [
        line for line in section.splitlines() if line.startswith("| ") and not line.startswith("| agents")
    ]


def test_the_readmes_results_rows_quote_the_reports_they_link() -> None:
    checked = 0
    for row in _results_rows():
        reports = _reports(row, ROOT / "README.md")
        if not reports:  # the paper's row: its figure is the paper's, linked to how ours differs
            assert "paper" in row, row
            continue
        cells = [c.strip() for c in row.strip().strip("|").split("|")]
        figures = " ".join(LINK.sub("]", c) for c in cells[1:-1])  # not the agents' names and budgets
        assert not _missing(figures, reports), (row, _missing(figures, reports))
        checked += 1
    assert checked >= 3


def test_docs_results_quotes_every_mean_and_error_as_a_linked_report_prints_it() -> None:
    page = ROOT / "docs" / "results.md"
    text = page.read_text()
    reports = _reports(text, page)
    assert len(reports) >= 3  # the shipped seeds, their parts (validation and test), the reproduction
    pairs = PLUS_MINUS.findall(text)
    assert len(pairs) >= 5
    assert not _missing(" ".join(pairs), reports)


def test_a_figure_no_report_prints_is_found_missing() -> None:
    report = ROOT / "benchmarks" / "results" / "overcooked" / "cpu" / "report.md"
    assert _missing("19.5 ± 0.9 and 11.4 ± 1.4, 39.9-81.5", [report]) == []
    assert _missing("19.5 ± 0.8 and 39.95", [report]) == ["19.5 ± 0.8", "39.95"]
