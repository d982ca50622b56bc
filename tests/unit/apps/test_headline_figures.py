"""The figures the README's results and the docs quote are those the release tables give: the README's results
table is what `cec results docs/results.yaml` prints from them, each of its rows' figures is printed on the
release page the row links, docs/results.md holds the per-kitchen table the same command prints, and every
other figure of those pages is printed by a report they link (a figure retyped by hand, or left behind when a
table or report was regenerated, fails here)."""

from __future__ import annotations

import functools
import re
import shlex
from pathlib import Path

from apps import results_table

ROOT = Path(__file__).resolve().parents[3]
README = ROOT / "README.md"
SPEC = ROOT / "docs" / "results.yaml"
LINK = re.compile(r"\]\(([^)\s]+)\)")
PLUS_MINUS = re.compile(r"(?<![\d.])\d+(?:\.\d+)? ± \d+(?:\.\d+)?(?![\d.])")
DECIMAL = re.compile(r"(?<![\d.])\d+\.\d+(?![\d.])")


def _reports(text: str, page: Path) -> list[Path]:
    """The committed reports `text` links (Markdown files under benchmarks/results/, or the diary and the
    lever comparisons `research/analyses/levers.py` writes under research/diary/), relative to `page`."""
    out = []
    written = (ROOT / "benchmarks" / "results", ROOT / "research" / "diary")
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


@functools.cache
def _printed() -> tuple[str, str]:
    """(the README's table, the per-kitchen table) as `cec results` prints them from the release tables."""
    spec, base = results_table.load_spec(SPEC)
    return results_table.headline(spec, base, ROOT), results_table.per_kitchen(spec, base)


def _results_section() -> str:
    return README.read_text().split("\n## Results\n", 1)[1].split("\n## ", 1)[0]


def test_the_readmes_results_table_is_what_cec_results_prints_from_the_release_tables() -> None:
    table, _ = _printed()
    assert table in _results_section(), "regenerate it: cec results docs/results.yaml"
    assert "`cec results docs/results.yaml`" in _results_section()
    rows = table.splitlines()[2:]
    assert 4 <= len(rows) <= 6  # one per shipped partner set, and the scripted cook beside them
    assert "cec_finetune_teacher" in rows[0]  # the strongest with the human proxies first


def test_each_row_of_the_table_is_printed_on_the_release_page_it_links() -> None:
    table, _ = _printed()
    checked = 0
    for row in table.splitlines()[2:]:
        cells = [c.strip() for c in row.strip().strip("|").split("|")]
        pages = _reports(cells[-1], README)
        assert pages, row
        figures = " ".join(cells[2:4]).replace("**", "")
        assert not _missing(figures, pages), (row, _missing(figures, pages))
        checked += 1
    assert checked == len(table.splitlines()[2:])


def test_the_scripted_teacher_is_named_in_every_row_that_learned_from_it() -> None:
    table, _ = _printed()
    for row in table.splitlines()[2:]:
        if "cec_teacher" in row or "cec_finetune_teacher" in row:
            assert "scripted teacher** (imitates a hand-written cook; not the paper's method)" in row, row


def test_docs_results_holds_the_per_kitchen_table_cec_results_prints() -> None:
    _, kitchens = _printed()
    assert kitchens in (ROOT / "docs" / "results.md").read_text(), (
        "regenerate it: cec results docs/results.yaml --per-kitchen"
    )


def test_the_rest_of_the_results_section_quotes_the_reports_it_links() -> None:
    table, _ = _printed()
    prose = _results_section().replace(table, "")
    reports = _reports(prose, README)
    assert len(reports) >= 3
    assert not _missing(prose, reports), _missing(prose, reports)


def test_the_commands_of_the_readme_parse() -> None:
    """`cec results` as the README gives it is a command of the `cec` CLI."""
    from apps.cli import build_parser

    args = build_parser().parse_args(shlex.split("results docs/results.yaml --per-kitchen"))
    assert args.func.__name__ == "_cmd_results" and args.per_kitchen


def test_docs_results_quotes_every_mean_and_error_as_a_linked_report_prints_it() -> None:
    page = ROOT / "docs" / "results.md"
    text = page.read_text()
    reports = _reports(text, page)
    assert len(reports) >= 3  # the shipped seeds, their parts (validation and test), the reproduction
    pairs = PLUS_MINUS.findall(text.replace(_printed()[1], ""))
    assert len(pairs) >= 5
    assert not _missing(" ".join(pairs), reports)


def test_docs_reproduce_overcooked_quotes_every_mean_and_error_as_a_linked_report_prints_it() -> None:
    page = ROOT / "docs" / "reproduce_overcooked.md"
    text = page.read_text()
    assert len(text.splitlines()) <= 400  # one curated page, not a diary
    pairs = PLUS_MINUS.findall(text)
    assert len(pairs) >= 20
    assert not _missing(" ".join(pairs), _reports(text, page))


def test_a_spec_that_names_no_table_or_a_missing_one_is_refused_by_name(tmp_path: Path) -> None:
    import pytest

    from cec.config import ConfigError

    spec = tmp_path / "results.yaml"
    spec.write_text("sets:\n  - {partner: mine, what: mine}\n")
    with pytest.raises(ConfigError, match="mine: give `kitchens:`"):
        results_table.headline(*results_table.load_spec(spec), tmp_path)
    (tmp_path / "tables").mkdir()
    spec.write_text("sets:\n  - {partner: mine, what: mine, kitchens: tables}\n")
    with pytest.raises(ConfigError, match="no table for cramped_room"):
        results_table.headline(*results_table.load_spec(spec), tmp_path)
    spec.write_text("sets:\n  - {partner: mine, what: mine, kitchen: tables}\n")
    with pytest.raises(ConfigError, match="kitchen"):
        results_table.load_spec(spec)


def test_a_figure_no_report_prints_is_found_missing() -> None:
    report = ROOT / "benchmarks" / "results" / "overcooked" / "cpu" / "report.md"
    assert _missing("19.5 ± 0.9 and 11.4 ± 1.4, 39.9-81.5", [report]) == []
    assert _missing("19.5 ± 0.8 and 39.95", [report]) == ["19.5 ± 0.8", "39.95"]
