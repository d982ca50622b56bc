"""The README as a newcomer reads it on a fresh clone: the two set-up commands first, how to reach the `cec`
command, the kitchen legend, and no link that fails inside the clone (README.md and docs/*.md)."""

from __future__ import annotations

import functools
import re
import subprocess
from pathlib import Path

import pytest

from cec.levels.ascii import AGENT_CHARS, TILE_CHARS

ROOT = Path(__file__).resolve().parents[3]
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^```.*?^```", re.MULTILINE | re.DOTALL)
CODE = re.compile(r"`[^`\n]*`")


def _links(page: Path) -> list[str]:
    """The targets of the page's Markdown links and images, outside code."""
    text = CODE.sub("", FENCE.sub("", page.read_text()))
    return LINK.findall(text)


def _anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text())
    return {_anchor(m) for m in re.findall(r"^#+\s+(.*)$", text, re.MULTILINE)}


@functools.cache
def _tracked() -> frozenset[Path] | None:
    """The files git tracks, and their folders: what a clone holds (None in a copy without git)."""
    if not (ROOT / ".git").exists():
        return None
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    files = [ROOT / name for name in out.decode().split("\0") if name]
    return frozenset([*files, *(parent for f in files for parent in f.parents)])


def test_the_two_set_up_commands_come_first_and_the_venv_is_named() -> None:
    head = README.read_text().splitlines()[:15]
    assert any(line.startswith("make up ") for line in head), head
    assert any(line.startswith("make test ") for line in head), head
    assert "source .venv/bin/activate" in README.read_text()


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_link_resolves_inside_the_clone(page: Path) -> None:
    """A relative link names a file or folder of this repository that git tracks (not one beside the clone,
    nor one only this working tree has), and its `#anchor`, if any, a heading of the page it points to."""
    bad = []
    for target in _links(page):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):
            continue  # a URL (https:, mailto:): not a file of the clone
        path_part, _, anchor = target.partition("#")
        path = (page.parent / path_part).resolve() if path_part else page
        tracked = _tracked()
        if ROOT not in (path, *path.parents) or not path.exists():
            bad.append(f"{target} (no such path in the repository)")
        elif tracked is not None and path not in tracked:
            bad.append(f"{target} (not tracked by git: a clone lacks it)")
        elif anchor and path.suffix == ".md" and anchor not in _anchors(path):
            bad.append(f"{target} (no heading #{anchor} in {path.name})")
    assert not bad, f"{page.relative_to(ROOT)}: {bad}"


def test_the_readme_links_the_kitchen_legend_and_the_legend_names_every_character() -> None:
    assert "docs/kitchens.md" in _links(README)
    legend = (ROOT / "docs" / "kitchens.md").read_text()
    for char in [*TILE_CHARS, *AGENT_CHARS]:
        assert f"| `{char}` |" in legend, f"{char!r} has no row in the legend"


def test_the_install_step_of_make_is_not_quiet() -> None:
    """`make up` on a fresh machine installs for minutes: pip's own lines show that it is moving."""
    makefile = (ROOT / "Makefile").read_text()
    install = [line for line in makefile.splitlines() if "pip install" in line and "-e " in line]
    assert install and all("--quiet" not in line and " -q" not in line for line in install), install


def test_both_commands_of_a_fresh_machine_install_the_redis_server_their_work_runs() -> None:
    """The README's two commands need only Python and make: the main job and the control plane's tests run a
    real `redis-server`, so each installs it where it is missing (what `make` would run, printed by -n)."""
    for target in ("up", "test"):
        plan = subprocess.run(["make", "-n", target], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert plan.returncode == 0, plan.stderr
        assert "command -v redis-server" in plan.stdout, target
        assert "apt-get install -y -qq redis-server" in plan.stdout, target


#: Words of a session that borrows a machine for timed calls, which a user with their own machine cannot
#: follow.
LENT_MACHINE = re.compile(
    r"\blent\b|\bborrowed\b|CEC_GIT_REV|device tool|\.whl\b|\btimed windows?\b|(?<!-)\bdevice time\b",
    re.IGNORECASE,
)


def _user_pages() -> list[Path]:
    """The pages a user reads: the README, docs/ and every README of benchmarks/results/."""
    pages = [
        README,
        *sorted((ROOT / "docs").rglob("*.md")),
        *sorted((ROOT / "benchmarks" / "results").rglob("README.md")),
    ]
    return [p for p in pages if p.is_file()]


def test_no_page_describes_a_lent_machine() -> None:
    """The docs are written for someone with their own machine (a GPU owner, a laptop): no borrowed or lent
    machine, no timed windows, no commit named through an environment variable, no wheels carried over."""
    found = [
        f"{page.relative_to(ROOT)}:{n}: {line.strip()[:100]}"
        for page in _user_pages()
        for n, line in enumerate(page.read_text().splitlines(), 1)
        if LENT_MACHINE.search(line)
    ]
    assert not found, found


def test_the_lent_machine_check_finds_those_words() -> None:
    assert LENT_MACHINE.search("trained on one lent H200")
    assert LENT_MACHINE.search("CEC_GIT_REV=abc bash benchmarks/gpu_session.sh window")
    assert LENT_MACHINE.search("15 minutes of device time")
    assert not LENT_MACHINE.search("the one-device time spread over the devices; the talent of a cook")
