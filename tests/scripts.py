"""Scripts under `benchmarks/`, `research/analyses/` and `scripts/` imported as modules, so that tests can
call their functions."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def _script(path: Path) -> Any:
    spec = importlib.util.spec_from_file_location(path.stem, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # what a dataclass of the script looks its module up by
    spec.loader.exec_module(module)
    return module


def benchmark(name: str) -> Any:
    """`benchmarks/<name>.py` as a fresh module."""
    return _script(ROOT / "benchmarks" / f"{name}.py")


def research(name: str) -> Any:
    """`research/analyses/<name>.py` as a fresh module."""
    return _script(ROOT / "research" / "analyses" / f"{name}.py")


def tool(name: str) -> Any:
    """`scripts/<name>.py` (the repository's own tools) as a fresh module."""
    return _script(ROOT / "scripts" / f"{name}.py")
