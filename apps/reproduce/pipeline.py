"""The skeleton both reproductions fill: plan -> train -> evaluate -> summarise -> report.

Every paper is a package `apps/reproduce/<paper>/` with the same modules (`PARTS`, checked by
`tests/unit/apps/test_reproduce_packages.py`), each filling one step of this skeleton:

    modes      its versions (quick, CPU or full, paper): presets, seeds, budgets, measured speeds
    paper      the paper's numbers and claims, as data (`apps/reproduce/paper_<paper>.yaml`)
    plan       `Zoo`: one `cec zoo build` spec a reproduction writes into its work folder
               (`<folder>/spec.yaml`, the zoo in `<folder>/zoo`): Overcooked one, Dual Destination one per
               variant; `Zoo.plan` checks it (`apps.zoo_build.plan_zoo`), `plan_line` sizes a run or a
               spec entry (`PlanLine`: its estimate from measured seconds per update, the share done);
               training is `Zoo.build`: finished runs skipped, interrupted ones resumed
    evaluate   `load_zoo_policies` (every entry, or an error naming those that cannot load), cross-play on
               `generated_levels` and the game's own, cached while what it depends on is unchanged
               (`cached_table`; several at once: `shared_tables`, `play_unclaimed`); the zoo exported
               as parameter files (`export_policies`), so that a work folder kept without its training
               states still reports (`played_table`, `--report-only`)
    summary    seeds as units: `cec.evaluation.seeds` (per seed XP and SP, the jackknife over seeds)
    report     the paper's own report beside the paper's numbers, with the recorded times of this module
               (`train_seconds`, `play_seconds`)
    command    `cec reproduce <paper>`: `add_subcommand` and the function that runs the steps in order

What each fills in: the runs of its spec (`<paper>.plan.zoo_spec`), which policies play which partners on
which levels, and what its report says beside the paper's numbers.
"""

from __future__ import annotations

import contextlib
import json
import math
import shutil
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, TextIO

import numpy as np
import yaml

from apps.machine import log_line
from cec.config import ConfigError
from cec.evaluation.curves import metrics_file, read_metrics_csv
from cec.evaluation.results import COMPRESSED, read_csv, stored, write_csv
from cec.training.metrics_file import read_rows

if TYPE_CHECKING:
    from apps.zoo_build import BuildResult, PlannedRun
    from cec.agents.policy import Policy
    from cec.agents.zoo import ZooEntry
    from cec.evaluation.results import EpisodeTable


PARTS = (
    "modes",
    "paper",
    "plan",
    "evaluate",
    "summary",
    "report",
    "command",
)  # every paper's package has these


def note(out: TextIO, msg: str) -> None:
    """One `reproduce` log line."""
    log_line(out, "reproduce", msg)


#: How often an invocation waiting for a table another one plays looks again (seconds).
POLL_S = 10.0


class Job(NamedTuple):
    """One cached table of `shared_tables`: where it lives, what it depends on (`cached_table`'s key), its
    log label and what plays it."""

    folder: Path
    key: Mapping[str, object]
    label: str
    play: Callable[[], EpisodeTable]


def cached_table(
    folder: Path, key: Mapping[str, object], play: Callable[[], EpisodeTable], *, label: str, log: TextIO
) -> EpisodeTable:
    """The result table `folder/results.csv` an earlier invocation wrote when `key` (what it depends on,
    stored beside it in `results.key.json`) is unchanged, else `play()`'s table, written there with the time
    `play()` took (`PLAY_TIME_FILE`) unless it recorded its own (a table of cached parts: the parts' times).
    The key is written last, so an invocation interrupted while playing plays again. Where another
    invocation is playing it (two builders of one work folder), this one waits for that table
    (`shared_tables`)."""
    return shared_tables([Job(folder, key, label, play)], log=log)[0]


def shared_tables(jobs: Sequence[Job], *, log: TextIO, poll_s: float = POLL_S) -> list[EpisodeTable]:
    """Each job's cached table (`cached_table`), in order. Several invocations may work on the same jobs at
    once (one per core): each plays the jobs no other has claimed (a job's folder lock,
    `cec.checkpoints.RunLock`, which the kernel drops however its holder ends), then waits for the others'
    tables, looking every `poll_s` seconds."""
    tables: dict[int, EpisodeTable] = {}
    waiting: set[int] = set()
    while True:
        for k, job in enumerate(jobs):
            if k not in tables and (table := _claimed_table(job, log)) is not None:
                tables[k] = table
        left = [k for k in range(len(jobs)) if k not in tables]
        if not left:
            return [tables[k] for k in range(len(jobs))]
        for k in sorted(set(left) - waiting):
            log_line(log, "reproduce", f"{jobs[k].label}played by another invocation; waiting for its table")
        waiting.update(left)
        time.sleep(poll_s)


def play_unclaimed(jobs: Sequence[Job], *, log: TextIO) -> int:
    """Plays each job's table that is neither stored nor claimed by another invocation, not waiting
    for the ones others play (a builder playing what is ready between training runs); the number played."""
    played = 0
    for job in jobs:
        if not stored_key(job.folder, job.key):
            played += _claimed_table(job, log) is not None
    return played


def stored_key(folder: Path, key: Mapping[str, object]) -> bool:
    """Whether `folder` holds a table an earlier invocation wrote under `key` (`cached_table`)."""
    key_file = folder / "results.key.json"
    stored = json.loads(key_file.read_text()) if key_file.exists() else None
    as_stored = json.loads(json.dumps(key))  # tuples as lists
    return results_file(folder).exists() and stored == as_stored


def stored_table(folder: Path, key: Mapping[str, object], *, label: str, log: TextIO) -> EpisodeTable | None:
    """The table an earlier invocation wrote in `folder` under `key` (`cached_table`), else None."""
    results = results_file(folder)
    if stored_key(folder, key):
        log_line(log, "reproduce", f"{label}cross-play results found ({results}); not played again")
        return read_csv(results)
    return None


def _claimed_table(job: Job, log: TextIO) -> EpisodeTable | None:
    """`cached_table`'s table, played under its folder's lock; None while another invocation holds it."""
    from cec.checkpoints import RunBusyError, RunLock

    folder, key, label, play = job
    if (table := stored_table(folder, key, label=label, log=log)) is not None:
        return table
    try:
        lock = RunLock(folder).acquire()
    except RunBusyError:
        return None
    try:
        if (table := stored_table(folder, key, label=label, log=log)) is not None:
            return table  # another invocation finished it meanwhile
        log_line(log, "reproduce", f"{label}cross-play")
        key_file = folder / "results.key.json"
        key_file.unlink(missing_ok=True)
        for suffix in COMPRESSED:  # a committed table the new one replaces
            (folder / f"results.csv{suffix}").unlink(missing_ok=True)
        time_file = folder / PLAY_TIME_FILE
        time_file.unlink(missing_ok=True)
        t0 = time.perf_counter()
        table = play()
        write_csv(table, folder / "results.csv")
        if not time_file.exists():
            time_file.write_text(json.dumps({"seconds": time.perf_counter() - t0}) + "\n")
        key_file.write_text(json.dumps(key, indent=1) + "\n")
        return table
    finally:
        lock.release()


@contextlib.contextmanager
def held(folder: Path, *, what: str, log: TextIO, poll_s: float = POLL_S) -> Iterator[None]:
    """`folder`'s lock (`cec.checkpoints.RunLock`) for the block, waiting while another invocation holds it
    (two invocations side by side writing the same report: one after the other, not into each other's
    files). `what`: what the other one is doing, for the log."""
    from cec.checkpoints import RunBusyError, RunLock

    lock, said = RunLock(folder), False
    while True:
        try:
            lock.acquire()
            break
        except RunBusyError:
            if not said:
                log_line(log, "reproduce", f"another invocation is writing {what}; waiting for it")
                said = True
            time.sleep(poll_s)
    try:
        yield
    finally:
        lock.release()


def results_file(folder: Path) -> Path:
    """`folder`'s cross-play table: `results.csv`, or `results.csv.gz` or `.bz2` where only that is there (a
    work folder committed with its tables compressed; read as it is)."""
    return stored(folder / "results.csv")


PLAY_TIME_FILE = "results.time.json"


def play_seconds(folder: Path) -> float:
    """How long playing `folder/results.csv` took when `cached_table` played it (NaN if not recorded:
    a table played before the time was kept)."""
    try:
        return float(json.loads((folder / PLAY_TIME_FILE).read_text())["seconds"])
    except (OSError, ValueError, KeyError, TypeError):
        return math.nan


def train_seconds(rows: list[dict[str, Any]]) -> float:
    """The training time a run's metrics rows record, also for a run an invocation found finished: each
    update's env steps per seed times the run's seeds, over the update's env steps/s (of all its seeds);
    compilation and checkpointing not included. 0 for no rows."""
    if not rows:
        return 0.0
    seeds = len({r["seed"] for r in rows})
    ordered = sorted({r["update"]: r for r in rows}.values(), key=lambda r: r["update"])
    sizes = np.diff([0, *(r["env_steps"] for r in ordered)])
    return float(
        sum(
            seeds * size / max(r.get("env_steps_per_s") or math.inf, 1e-9)
            for size, r in zip(sizes, ordered, strict=True)
        )
    )


def read_metrics(run_dir: Path) -> list[dict[str, Any]]:
    """A run's `metrics.jsonl` rows, or where a committed run folder kept only its `metrics.csv` (or
    `metrics.csv.gz`), that table's rows; [] when it has none yet."""
    path = run_dir / "metrics.jsonl"
    if path.exists():
        return read_rows(path)  # bounded, every line checked (a folder or device there: named)
    return read_metrics_csv(run_dir) if metrics_file(run_dir).is_file() else []


@dataclass(frozen=True)
class Zoo:
    """One zoo a reproduction trains: `spec` (a `cec zoo build` spec), written to `folder/spec.yaml` under
    the comment line `# Written by <header>.`, built into `folder/zoo`."""

    folder: Path
    spec: dict[str, object]
    header: str

    @property
    def zoo_dir(self) -> Path:
        return self.folder / "zoo"

    def write_spec(self) -> Path:
        self.folder.mkdir(parents=True, exist_ok=True)
        path = self.folder / "spec.yaml"
        text = yaml.safe_dump(self.spec, sort_keys=False)
        path.write_text(f"# Written by {self.header}.\n" + text)
        return path

    def plan(self) -> list[PlannedRun]:
        """The runs of the spec, written first, as training does (so a finished run trained with another
        config is refused: `ConfigError`)."""
        from apps.zoo_build import plan_zoo

        return plan_zoo(self.write_spec(), self.zoo_dir)

    def build(
        self, *, progress: bool, log: TextIO, wait: bool = True,
        between: Callable[[list[PlannedRun]], object] | None = None,
    ) -> BuildResult:  # fmt: skip
        """Writes the spec and builds the zoo (resuming, skipping finished runs): `build_zoo`'s result
        (`between`: its work between runs)."""
        from apps.zoo_build import build_zoo

        return build_zoo(
            self.write_spec(), self.zoo_dir, progress=progress, log=log, wait=wait, between=between
        )


@dataclass(frozen=True)
class PlanLine:
    """One training run (or one spec entry's runs) with its size, estimated time and how much of it is
    checkpointed; `zoo` names the zoo it belongs to where a reproduction trains several (the variant);
    `algorithm` the run's training algorithm where it was read from the run's config."""

    run: str
    seeds: int
    env_steps: int
    updates: int
    estimate_s: float
    done: float  # share of its seed-updates checkpointed under the work directory
    zoo: str = ""
    algorithm: str = ""

    @property
    def left_s(self) -> float:
        return self.estimate_s * (1.0 - self.done)


def plan_line(run: str, runs: Sequence[PlannedRun], seconds_per_update: float, zoo: str = "") -> PlanLine:
    """The `PlanLine` of `runs` (one spec entry's, of one size): their seeds together, the estimate
    `seconds_per_update` (NaN: not measured) x updates x seeds, the share already trained."""
    from apps.zoo_build import done_fraction

    cfg, n = runs[0].config, sum(len(r.seeds) for r in runs)
    estimate = seconds_per_update * cfg.num_updates * n
    return PlanLine(run, n, cfg.total_env_steps, cfg.num_updates, estimate, done_fraction(runs), zoo)


def generated_levels(n: int) -> str:
    """The level spec of the first `n` held-out generated levels (`generated_000,generated_001,...`)."""
    return ",".join(f"generated_{i:03d}" for i in range(n))


def load_zoo_policies(manifest: str | Path, where: str) -> list[Policy]:
    """Every policy of a zoo manifest; a `ConfigError` (`<where>: ...`) naming each entry that cannot be
    loaded."""
    from cec.agents.zoo import load_zoo

    return load_entry_policies(load_zoo(manifest), where)


def load_entry_policies(entries: Sequence[ZooEntry], where: str) -> list[Policy]:
    """The policy of every zoo entry; a `ConfigError` (`<where>: ...`) naming each that cannot be loaded."""
    from cec.agents.policy import load_policies

    policies, skipped = load_policies(entries)
    if skipped:
        reasons = "; ".join(f"{s.name}: {s.reason}" for s in skipped)
        raise ConfigError(f"{where}: zoo entries could not be loaded: {reasons}")
    return policies


def zoo_entries(manifest: str | Path) -> list[list[Any]]:
    """What a zoo's cross-play depends on, per entry: name, seed, checkpoint and the state's SHA-256 that
    `cec zoo build` pinned (for a `cached_table` key)."""
    from cec.agents.zoo import load_zoo

    return [[e.name, e.seed, str(e.checkpoint), e.sha256] for e in load_zoo(manifest)]


POLICIES = "policies"  # beside a result table: the zoo's policies as parameter files (what a report needs)
SOURCE = "source.json"  # in POLICIES: the zoo entries they were exported from
POLICIES_SOURCE = f"{POLICIES}/{SOURCE}"


def export_policies(zoo_manifest: Path, folder: Path, *, log: TextIO) -> Path:
    """The zoo as one-seed parameter files (`cec zoo export`: no Adam state, no rollout carry) in `folder`,
    with their manifest, which it returns. Exported again only when the zoo changed (the entries they came
    from, with their states' SHA-256, are kept in `folder/source.json`, written last)."""
    from apps.zoo_build import MANIFEST, export_zoo

    source, manifest = folder / SOURCE, folder / MANIFEST
    entries = json.loads(json.dumps(zoo_entries(zoo_manifest)))  # as stored: tuples as lists
    if manifest.is_file() and source.is_file() and json.loads(source.read_text()) == entries:
        return manifest
    if folder.exists():
        shutil.rmtree(folder)  # an older zoo's: none may linger under a name this one dropped
    export_zoo(zoo_manifest, folder)
    source.write_text(json.dumps(entries, indent=1) + "\n")
    note(log, f"{len(entries)} policies exported to {folder}")
    return manifest


def played_table(work: Path, command: str, *needs: str) -> EpisodeTable:
    """The cross-play table that a complete `cec reproduce <command>` left in `work` (for `--report-only`),
    checking that it and `needs` (paths under `work`) are there; a `ConfigError` naming what is missing."""
    # the key is written after the table (`cached_table`): its presence says the playing finished
    paths = [results_file(work), work / "results.key.json", *(work / n for n in needs)]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise ConfigError(
            f"--report-only needs a work folder that a complete `cec reproduce {command}` left behind; "
            f"missing: {', '.join(missing)} (run the command without --report-only, or pass --work)"
        )
    return read_csv(paths[0])
