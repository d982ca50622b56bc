"""The skeleton both reproductions fill: plan -> train -> evaluate -> summarise -> report.

    plan       `Zoo`: one `cec zoo build` spec a reproduction writes into its work folder
               (`<folder>/spec.yaml`, the zoo in `<folder>/zoo`): Overcooked one, Dual Destination one per
               variant; `Zoo.plan` checks it (`apps.zoo_build.plan_zoo`), `plan_line` sizes a run or a
               spec entry (`PlanLine`: its estimate from measured seconds per update, the share done)
    train      `Zoo.build`: finished runs skipped, interrupted ones resumed
    evaluate   `load_zoo_policies` (every entry, or an error naming those that cannot load), cross-play on
               `generated_levels` and the game's own, cached while the zoo is unchanged
               (`common.cached_table`, keyed by `zoo_entries`); the zoo exported as parameter files
               (`export_policies`), so that a work folder kept without its training states still
               reports (`played_table`, `--report-only`)
    summarise  seeds as units: `cec.evaluation.seeds` (per seed XP and SP, the jackknife over seeds)
    report     each reproduction's own (`overcooked.write_report`, `dd_report.write_report`), with the
               recorded times of `common`

What each fills in: the runs of its spec (`overcooked.zoo_spec`, `dual_destination.zoo_spec`), which
policies play which partners on which levels, and what its report says beside the paper's numbers.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import yaml

from apps.machine import log_line
from cec.config import ConfigError

if TYPE_CHECKING:
    from apps.zoo_build import BuildResult, PlannedRun


def note(out: TextIO, msg: str) -> None:
    """One `reproduce` log line."""
    log_line(out, "reproduce", msg)


@dataclass(frozen=True)
class Zoo:
    """One zoo a reproduction trains: `spec` (a `cec zoo build` spec), written to `folder/spec.yaml` under
    the comment line `# Written by <header>.`, built into `folder/zoo`."""

    folder: Path
    spec: dict[str, Any]
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

    def build(self, *, progress: bool, log: TextIO, wait: bool = True) -> BuildResult:
        """Writes the spec and builds the zoo (resuming, skipping finished runs): `build_zoo`'s result."""
        from apps.zoo_build import build_zoo

        return build_zoo(self.write_spec(), self.zoo_dir, progress=progress, log=log, wait=wait)


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


def load_zoo_policies(manifest: str | Path, where: str) -> list[Any]:
    """Every policy of a zoo manifest; a `ConfigError` (`<where>: ...`) naming each entry that cannot be
    loaded."""
    from cec.agents.policy import load_policies
    from cec.agents.zoo import load_zoo

    policies, skipped = load_policies(load_zoo(manifest))
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
    import json
    import shutil

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


def played_table(work: Path, command: str, *needs: str) -> Any:
    """The cross-play table that a complete `cec reproduce <command>` left in `work` (for `--report-only`),
    checking that it and `needs` (paths under `work`) are there; a `ConfigError` naming what is missing."""
    from apps.reproduce.common import results_file
    from cec.evaluation.results import read_csv

    # the key is written after the table (`common.cached_table`): its presence says the playing finished
    paths = [results_file(work), work / "results.key.json", *(work / n for n in needs)]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise ConfigError(
            f"--report-only needs a work folder that a complete `cec reproduce {command}` left behind; "
            f"missing: {', '.join(missing)} (run the command without --report-only, or pass --work)"
        )
    return read_csv(paths[0])
