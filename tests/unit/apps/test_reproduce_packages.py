"""Every paper's reproduction has one shape (issue 61): a package `apps/reproduce/<paper>/` with the modules
of `apps.reproduce.pipeline.PARTS`, each doing its one job, and a package docstring that names each of its
modules, so that a part a paper adds beside them (or lacks) says why there.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

from apps.reproduce.pipeline import PARTS

REPRODUCE = Path(__file__).resolve().parents[3] / "apps" / "reproduce"
PAPERS = sorted(p.name for p in REPRODUCE.iterdir() if (p / "__init__.py").is_file())


def test_every_game_of_cec_reproduce_is_a_paper_package() -> None:
    assert PAPERS == ["dual_destination", "overcooked"]
    # nothing but the packages, the shared skeleton and the papers' data beside them
    loose = sorted(p.name for p in REPRODUCE.glob("*.py"))
    assert loose == ["__init__.py", "pipeline.py"]


@pytest.mark.parametrize("paper", PAPERS)
def test_a_paper_package_has_every_part_and_its_docstring_names_each_module(paper: str) -> None:
    folder = REPRODUCE / paper
    modules = sorted(p.stem for p in folder.glob("*.py") if p.stem != "__init__")
    assert set(PARTS) <= set(modules), f"{paper} lacks {sorted(set(PARTS) - set(modules))}"
    docstring = ast.get_docstring(ast.parse((folder / "__init__.py").read_text())) or ""
    unnamed = [m for m in modules if f"\n    {m} " not in f"\n{docstring}"]
    assert unnamed == [], f"apps/reproduce/{paper}/__init__.py does not say what {unnamed} are"


@pytest.mark.parametrize("paper", PAPERS)
def test_a_paper_package_fills_the_skeleton_the_same_way(paper: str) -> None:
    """The names the `cec reproduce` command and the pipeline rely on, in the same module of every paper."""
    command = importlib.import_module(f"apps.reproduce.{paper}.command")
    modes = importlib.import_module(f"apps.reproduce.{paper}.modes")
    plan = importlib.import_module(f"apps.reproduce.{paper}.plan")
    paper_module = importlib.import_module(f"apps.reproduce.{paper}.paper")
    report = importlib.import_module(f"apps.reproduce.{paper}.report")
    assert callable(command.add_subcommand)
    assert modes.MODES and all(m.name == name for name, m in modes.MODES.items())
    assert callable(plan.zoo_spec) and callable(plan.zoo) and callable(plan.plan_lines)
    assert paper_module.PAPER_FILE.is_file() and paper_module.PAPER_FILE.parent == REPRODUCE
    assert callable(report.write_report)
