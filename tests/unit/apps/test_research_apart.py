"""The product stands apart from its record (DESIGN rule 15): `cec`, `services` and `apps` import nothing from
`research/` or `benchmarks/` (import-linter's contract, run by `make lint`), and read no file a research or
benchmark script writes: no path under those folders appears in the product's code or data, where a read
would have to name it. Docstrings may cite the record; a string the code uses may not."""

from __future__ import annotations

import ast
import json
import re
import tomllib
from collections.abc import Iterator
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[3]
PRODUCT = ("cec", "services", "apps")
RECORD = ("research", "benchmarks")
#: A path that enters the record: `research/...`, `.../benchmarks/...`, or the bare folder name (a component).
UNDER_RECORD = re.compile(rf"(^|[/\\])({'|'.join(RECORD)})([/\\]|$)")
DATA_SUFFIXES = (".yaml", ".yml", ".json", ".toml")


def _docstrings(tree: ast.AST) -> set[int]:
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                out.add(id(first.value))
    return out


def code_paths(source: str) -> list[tuple[int, str]]:
    """The string constants of a module (docstrings aside) that name a path in the record, with their line."""
    tree = ast.parse(source)
    docs = _docstrings(tree)
    return [
        (node.lineno, node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant)
        and isinstance(node.value, str)
        and id(node) not in docs
        and UNDER_RECORD.search(node.value)
    ]


def _strings(value: object) -> Iterator[str]:
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _strings(key)
            yield from _strings(item)
    elif isinstance(value, list | tuple):
        for item in value:
            yield from _strings(item)
    elif isinstance(value, str):
        yield value


def data_paths(path: Path) -> list[str]:
    """The strings of a data file (YAML, JSON, TOML; comments aside) that name a path in the record."""
    text = path.read_text()
    if path.suffix == ".json":
        data = json.loads(text)
    elif path.suffix == ".toml":
        data = tomllib.loads(text)
    else:
        data = list(yaml.safe_load_all(text))
    return [s for s in _strings(data) if UNDER_RECORD.search(s)]


def _product_files(suffixes: tuple[str, ...]) -> list[Path]:
    files = (f for name in PRODUCT for f in (ROOT / name).rglob("*"))
    return sorted(f for f in files if f.suffix in suffixes and f.is_file())


def test_the_product_names_no_path_in_research_or_benchmarks() -> None:
    found = [
        f"{f.relative_to(ROOT)}:{line}: {text[:120]!r}"
        for f in _product_files((".py",))
        for line, text in code_paths(f.read_text())
    ]
    found += [
        f"{f.relative_to(ROOT)}: {text[:120]!r}"
        for f in _product_files(DATA_SUFFIXES)
        for text in data_paths(f)
    ]
    assert not found, (
        "the product reads what a research or benchmark script writes (or could): "
        f"{found}; make the result a product command's output (apps/) or ship it under cec/shipped/"
    )


def test_the_check_finds_a_read_of_the_record_and_lets_a_citation_pass(tmp_path: Path) -> None:
    module = '''"""Cites research/diary/reproduce_overcooked.md, which is fine."""
from pathlib import Path

ROOT = Path(__file__).parents[1]


def load():
    """Reads nothing from benchmarks/ itself."""
    a = (ROOT / "benchmarks/results/overcooked/cpu/report.md").read_text()
    b = ROOT / "research" / "diary"
    c = "runs/benchmarks_old"  # a name that only contains the word
    return a, b, c
'''
    assert sorted(line for line, _ in code_paths(module)) == [9, 10]
    data = tmp_path / "zoo.yaml"
    data.write_text(
        "# from benchmarks/results/x (a comment)\nentries:\n- checkpoint: research/results/x.json\n"
    )
    assert data_paths(data) == ["research/results/x.json"]


def test_the_import_contract_forbids_research_and_benchmarks_to_the_product() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    assert config["include_external_packages"]  # research/ and benchmarks/ are outside the root packages
    contracts = [
        c
        for c in config["contracts"]
        if c["type"] == "forbidden" and set(c["forbidden_modules"]) >= set(RECORD)
    ]
    assert contracts and set(contracts[0]["source_modules"]) == set(PRODUCT)
    assert "lint-imports" in (ROOT / "Makefile").read_text().split("\nlint:", 1)[1].split("\n\n", 1)[0]
