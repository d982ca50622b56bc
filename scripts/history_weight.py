"""History that stops growing (DESIGN rule 17): every file version committed since the round's base commit
(594daee) is at most 1 MiB, outside the shipped policies (`cec/shipped/`), and outside one allowed place:

    carry/    a run that must outlive a working session commits its state here in a compact form (parameters
              and optimizer state only), at most once a session (carry commits at least `SESSION` apart: a
              session lasts 3 hours), and every version committed here since the base counts against
              the round's budget of 120 MB in all.

Everything else regenerable (training states, work folders, tables) stays out of git: a release goes out
as a bundle (`cec zoo export`), a result table compressed (`.csv.bz2`). `make lint` runs this:

    python scripts/history_weight.py                # exit 1, naming each file and commit, if over
    python scripts/history_weight.py --base <rev>   # from another base commit

A checkout without git, or a shallow clone that lacks the base (every commit it holds is newer), checks
what it has: the first nothing, the second every commit it holds.
"""

from __future__ import annotations

import argparse
import datetime
import itertools
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASE = "594daee"
MAX_BLOB = 1 << 20
SHIPPED = "cec/shipped/"
CARRY, CARRY_BUDGET = "carry/", 120_000_000
SESSION = datetime.timedelta(hours=3)  # a working session's length: two carries closer than this share one


@dataclass(frozen=True)
class Blob:
    """A file version first committed since the base: its path (the first one git names it by), size."""

    path: str
    size: int
    commit: str
    when: str = ""  # the commit's time, ISO 8601


def _git(repo: Path, *args: str, stdin: str | None = None) -> str:
    command = ["git", "-C", str(repo), "-c", "core.quotePath=off", *args]  # paths as they are (UTF-8)
    out = subprocess.run(command, input=stdin, capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"git {' '.join(args)}: {out.stderr.strip()}")
    return out.stdout


def new_blobs(repo: Path, base: str) -> list[Blob]:
    """Every file version added or changed by a commit reachable from HEAD and not from `base` (all of HEAD's
    commits if `base` is unknown), with the commit that committed it."""
    known = subprocess.run(
        ["git", "-C", str(repo), "rev-parse", "--verify", "--quiet", f"{base}^{{commit}}"],
        capture_output=True,
    )
    since = [f"^{base}"] if known.returncode == 0 else []
    log = _git(
        repo, "log", "--reverse", "--no-renames", "--raw", "--no-abbrev", "-c", "--diff-filter=AM",
        "--format=commit %H %cI", "HEAD", *since,
    )  # fmt: skip
    versions: list[tuple[str, str, str, str]] = []  # (object, path, commit, time)
    commit = when = ""
    for line in log.splitlines():
        if line.startswith("commit "):
            _, commit, when = line.split()
        elif line.startswith(":") and "\t" in line:
            fields, path = line.split("\t", 1)
            versions.append((fields.split()[-2], path, commit[:10], when))  # the version the commit made
    if not versions:
        return []
    listing = _git(
        repo, "cat-file", "--batch-check=%(objectname) %(objectsize)", stdin="\n".join(v[0] for v in versions)
    )
    sizes = dict(line.split() for line in listing.splitlines())
    return [Blob(path, int(sizes[name]), commit, when) for name, path, commit, when in versions]


def problems(blobs: list[Blob]) -> list[str]:
    """What the rule refuses: a file over 1 MiB outside cec/shipped/ and carry/, carry/ over its budget."""
    out = [
        f"{b.path} ({b.size / 2**20:.1f} MiB, commit {b.commit})"
        for b in blobs
        if b.size > MAX_BLOB and not b.path.startswith((SHIPPED, CARRY))
    ]
    carried = [b for b in blobs if b.path.startswith(CARRY)]
    total = sum(b.size for b in carried)
    if total > CARRY_BUDGET:
        out.append(
            f"{CARRY} took {total / 1e6:.1f} MB since the base (its budget: {CARRY_BUDGET / 1e6:.0f} MB)"
        )
    times = sorted({(datetime.datetime.fromisoformat(b.when), b.commit) for b in carried})
    out += [
        f"{CARRY} committed twice within {SESSION} ({a} at {ta:%Y-%m-%d %H:%M}, {b} at {tb:%H:%M}; once a "
        "session at most)"
        for (ta, a), (tb, b) in itertools.pairwise(times)
        if tb - ta < SESSION
    ]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", default=BASE, help=f"the round's base commit (default {BASE})")
    parser.add_argument("--repo", type=Path, default=ROOT, help="the repository (default: this one)")
    args = parser.parse_args(argv)
    if not (args.repo / ".git").exists():
        print(f"history weight: {args.repo} is not a git checkout; nothing to check")
        return 0
    found = problems(new_blobs(args.repo, args.base))
    if found:
        print(
            f"history weight: since {args.base}, history keeps what it must not: {'; '.join(found)}.\n"
            f"Only the shipped policies ({SHIPPED}) may be over {MAX_BLOB >> 20} MiB. A run that must "
            "outlive a working session commits a compact state (parameters and optimizer state only) under "
            f"{CARRY}, at most once a session and {CARRY_BUDGET / 1e6:.0f} MB in all for the round; anything "
            "else regenerable stays out of git (a release: `cec zoo export`; a table: .csv.bz2). Take the "
            "file out of the commit that added it (amend it) before the commit is shared.",
            file=sys.stderr,
        )
        return 1
    print(f"history weight: every file version since {args.base} is within the rule")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
