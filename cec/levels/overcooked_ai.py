"""Where the installed overcooked-ai package (the `peers` extra) keeps its data, found without importing it:
its layout files (the test set's drawn kitchens, `cec.levels.heldout_build`) and its human-human games
(`cec humans import`)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

PACKAGE = "overcooked_ai_py"
PACKAGE_VERSION = "1.1.0"


def package_dir() -> Path | None:
    """The installed `overcooked_ai_py` folder, or None when the package is not installed."""
    spec = importlib.util.find_spec(PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))
