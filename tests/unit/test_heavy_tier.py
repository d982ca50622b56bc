"""The heavy tier (tests/heavy_tier.txt, read into tests/conftest.py `HEAVY`), which `make test` leaves out
and `make test-all` runs: every entry names a test that exists, so a renamed test cannot leave a stale entry
behind, and pytest marks exactly those tests `heavy`."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.conftest import HEAVY

REPO = Path(__file__).resolve().parents[2]


def test_the_heavy_tier_names_existing_tests_and_marks_exactly_them() -> None:
    files = sorted({nodeid.split("::")[0] for nodeid in HEAVY})
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", "-m", "heavy",
         *files],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    collected = {line for line in proc.stdout.splitlines() if "::" in line}
    assert collected == set(HEAVY), (sorted(set(HEAVY) - collected), sorted(collected - set(HEAVY)))


def _suite_command(target: str) -> str:
    """The pytest command line `make <target>` runs, as make expands it (`make -n`: printed, not run)."""
    proc = subprocess.run(["make", "-n", target], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return next(line for line in proc.stdout.splitlines() if "-m pytest" in line)


def test_make_test_leaves_the_heavy_tier_out_and_make_test_all_runs_it() -> None:
    gate, everything = _suite_command("test"), _suite_command("test-all")
    assert gate.endswith('tests/services -m "not heavy"'), gate
    assert gate.removesuffix(' -m "not heavy"') == everything
