"""The import structure a contributor relies on: no module import cycles, and every code folder a package.

The layer contract itself (cec <- services <- apps) is import-linter's, in `make lint`. What it cannot see
is checked here: a cycle between two modules (held together by function-local imports, it breaks as soon
as one of them is imported first from a new place), and a folder without `__init__.py`, which the import
graph silently leaves out.
"""

from __future__ import annotations

import ast
from pathlib import Path

import grimp
import networkx as nx

ROOT = Path(__file__).resolve().parents[3]
PACKAGES = ("cec", "services", "apps")
MAX_LINES = 500
# DESIGN.md rule 14: no module in apps/ or services/ grows past about 700 lines (issue 61, item 1)
ONE_JOB_LINES = 700
OVER_ONE_JOB: set[str] = set()  # modules an open issue splits, only while they are over


def _graph() -> nx.DiGraph:
    # Every import statement, function-local ones and `if TYPE_CHECKING:` ones included: a type that two
    # modules take from each other is a circle too (the type belongs to one of them, or to a third).
    imports = grimp.build_graph(*PACKAGES, exclude_type_checking_imports=False)
    graph = nx.DiGraph()
    for module in imports.modules:
        graph.add_node(module)
        for target in imports.find_modules_directly_imported_by(module):
            graph.add_edge(module, target)
    return graph


def cycles(graph: nx.DiGraph) -> list[list[str]]:
    return sorted(sorted(c) for c in nx.strongly_connected_components(graph) if len(c) > 1)


def test_no_import_cycles_between_modules() -> None:
    graph = _graph()
    assert "cec.training.trainer" in graph and "services.stack" in graph  # the graph sees the whole tree
    assert cycles(graph) == []


def test_the_cycle_check_finds_a_cycle() -> None:
    graph = _graph()
    graph.add_edge("cec.levels.level", "cec.levels.generator")  # the generator imports level.py
    assert any("cec.levels.level" in c and "cec.levels.generator" in c for c in cycles(graph))


def test_every_code_folder_is_a_package() -> None:
    skip = {"__pycache__", "data", "shipped", "static"}
    missing = [
        str(folder.relative_to(ROOT))
        for name in PACKAGES
        for folder in [ROOT / name, *(ROOT / name).rglob("*")]
        if folder.is_dir()
        and not skip & set(folder.relative_to(ROOT).parts)
        and any(folder.glob("*.py"))
        and not (folder / "__init__.py").is_file()
    ]
    assert missing == []


def test_a_long_module_says_why() -> None:
    """Over ~500 lines a module must say in its docstring why it stays one (a `Size:` paragraph)."""
    long = []
    for name in PACKAGES:
        for path in sorted((ROOT / name).rglob("*.py")):
            if "v1" in path.parts:  # generated gRPC stubs
                continue
            text = path.read_text()
            lines = text.count("\n")
            docstring = ast.get_docstring(ast.parse(text)) or ""
            if lines > MAX_LINES and "Size:" not in docstring:
                long.append(f"{path.relative_to(ROOT)} ({lines} lines)")
    assert long == []


def test_no_module_in_apps_or_services_is_over_the_limit() -> None:
    """A module of an app or a service has one job (DESIGN.md rule 14): none is over ~700 lines, whatever its
    docstring says; `OVER_ONE_JOB` names the ones an open issue splits, and only while they are over."""
    sizes = {
        str(path.relative_to(ROOT)): path.read_text().count("\n")
        for name in ("apps", "services")
        for path in sorted((ROOT / name).rglob("*.py"))
    }
    over = sorted(f"{p} ({n} lines)" for p, n in sizes.items() if n > ONE_JOB_LINES and p not in OVER_ONE_JOB)
    assert over == []
    assert sorted(p for p in OVER_ONE_JOB if sizes.get(p, 0) <= ONE_JOB_LINES) == []  # split: off the list


# issue 61, item 1: a function over ~100 lines of code (its docstring not counted) says why in its docstring
FUNCTION_LINES = 100


def unexplained_long_functions(source: str) -> list[str]:
    """The functions of `source` over `FUNCTION_LINES` lines of code whose docstring has no "Long because"."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        docstring = ast.get_docstring(node) or ""
        first = node.body[0]
        doc_lines = first.end_lineno - first.lineno + 1 if docstring and first.end_lineno else 0
        lines = (node.end_lineno or node.lineno) - node.lineno + 1 - doc_lines
        if lines > FUNCTION_LINES and "Long because" not in docstring:
            found.append(f"{node.name} ({lines} lines)")
    return found


def test_a_long_function_says_why() -> None:
    long = [
        f"{path.relative_to(ROOT)}: {name}"
        for package in PACKAGES
        for path in sorted((ROOT / package).rglob("*.py"))
        if "v1" not in path.parts  # generated gRPC stubs
        for name in unexplained_long_functions(path.read_text())
    ]
    assert long == [], "split these functions, or say in their docstrings why they are long ('Long because')"


def test_the_function_check_counts_code_not_its_docstring() -> None:
    body = "".join(f"    x{i} = {i}\n" for i in range(FUNCTION_LINES - 1))
    docstring = '    """Twenty lines.\n' + "    more\n" * 18 + '    """\n'
    assert unexplained_long_functions(f"def f():\n{docstring}{body}") == []  # 100 lines with the def
    assert unexplained_long_functions(f"def f():\n{docstring}{body}    y = 1\n") == ["f (101 lines)"]
    reason = '    """Long because it is a table of steps."""\n'
    assert unexplained_long_functions(f"def f():\n{reason}{body}    y = 1\n") == []
