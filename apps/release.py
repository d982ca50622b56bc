"""`cec release RUN --prefix NAME [--ship]`: a service-made run's release, chosen on validation, reported on
test, shipped, by one command (DESIGN.md rules 13 and 15).

    cec up --config configs/up/release.yaml            # trains the seeds; the evaluator keeps the record
    cec release runs/up-release --prefix rel21m        # choose, test once, report  (RUN/release/)
    cec release runs/up-release --prefix rel21m --ship # ... and ship it in place of the family's seeds

In order, each step's tables kept under RUN/release/ so that a second call reuses them:

1. **Candidates**: the checkpoints with the best validation cross-play in the evaluator's training record
   (`RUN/eval/record.csv`: a fixed quarter of the validation kitchens per checkpoint), and the last one.
2. **Choice, on validation only**: each candidate's seeds with each other on the whole validation set (the
   100 generated kitchens; 400-step episodes, both seats, one episode per pairing and kitchen, sampled
   actions, common random numbers). The highest cross-play is chosen (`cec.evaluation.choice`: a candidate
   without a finite figure stops the command, naming it).
3. **Against what ships**: the shipped seeds of the family (`--family`, `cec_teacher`) on the same episodes,
   and each release seed with each of them, for an exact permutation test over the pooled seeds.
   `--ship` ships only a release that is not worse on validation (its cross-play at least theirs).
4. **Test, once, after the choice**: the release's own test set (`test2`, fresh) and the first test set
   (`test`, reused: read before, reported as such), each recorded in the ledger
   (`cec/levels/data/test_reads.csv`) when played; never played again for the same choice.
5. **Beside it**: the classic five (4 episodes per pairing), the human proxies in their own kitchens, the
   scripted cook with its two controls (an untrained network of the recipe, and a partner that stays
   put), the same tables at the authors' 100-step episodes.
6. **Report**: RUN/release/README.md, every figure from the tables beside it; the record's plot.
7. **Ship** (`--ship`): each seed as a one-seed parameter checkpoint `cec/shipped/<prefix>-s<seed>` under the
   family's label (what `cec play serve --partner cec_teacher` plays), replacing the family's entries in
   `cec/shipped/zoo.yaml`; the report, its tables and the record in `docs/releases/<prefix>/`.

Size: one release's steps in the order they must run (choice before test, test once); each is a short
function over the same evaluation helpers.
"""

from __future__ import annotations

import argparse
import bz2
import dataclasses
import json
import logging
import math
import shutil
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml

from cec import checkpoints
from cec.agents.policy import (
    Policy,
    checkpoint_seeds,
    load_policy,
    random_policy,
    save_policy,
    scripted_policy,
)
from cec.agents.zoo import SHIPPED_ZOO, ZooEntry, load_zoo
from cec.config import ConfigError, from_dict
from cec.evaluation.checkpoint_results import read_record
from cec.evaluation.choice import choose
from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels
from cec.evaluation.markdown import Templates, num, pm, table
from cec.evaluation.parts import PartScore, part_scores
from cec.evaluation.results import EpisodeTable, read_csv, write_csv
from cec.evaluation.stats import compare_crossplay, permutation_crossplay, sem
from cec.levels import ledger
from cec.training.config import TrainConfig

log = logging.getLogger("cec.release")
TEMPLATES = Templates(Path(__file__).with_name("templates"))
REPO = Path(__file__).resolve().parents[1]
#: The README's protocol.
STEPS, AUTHORS_STEPS = 400, 100
CLASSIC_EPISODES = 4
#: The level set the evaluator records validation under (configs/evaluator.yaml) and the group it scores.
RECORD_SET, RECORD_GROUP = "validation", "cross_play"


@dataclasses.dataclass(frozen=True)
class Sets:
    """The level specs a release is played on (`cec.levels.named`); tests give small ones."""

    validation: str = "generated"
    test: str = "test2"
    reused_test: str = "test"
    classic: str = "classic"


# ---------------------------------------------------------------------------------------------------------
# THE RUN: its checkpoints, its record, its seeds
# ---------------------------------------------------------------------------------------------------------


def checkpoints_of(run: Path) -> dict[int, Path]:
    """{update: checkpoint} of the run's readable checkpoints."""
    store = checkpoints.CheckpointStore(run, keep_last=1)
    return {c.update: c.path for c in store.list()}


def candidates(run: Path, n: int) -> list[int]:
    """The updates of the `n` checkpoints with the best recorded validation cross-play, then the last one
    (each on disk), best first; `ConfigError` when the run has no checkpoint or no such record."""
    on_disk = checkpoints_of(run)
    if not on_disk:
        raise ConfigError(
            f"{run} has no checkpoint: train it first (cec up --config configs/up/release.yaml)"
        )
    rows = [
        r
        for r in read_record(run / "eval" / "record.csv")
        if (r["partner_group"], r["level_set"]) == (RECORD_GROUP, RECORD_SET) and r["update"] in on_disk
    ]
    scored = {r["update"]: r["return_mean"] for r in rows if r["return_mean"] is not None}
    if not scored:
        raise ConfigError(
            f"{run}/eval/record.csv has no {RECORD_GROUP} score on {RECORD_SET} for a checkpoint on disk: "
            "the evaluator scores a run of several seeds as it trains (cec up, configs/evaluator.yaml)"
        )
    best = sorted(scored, key=lambda u: (-scored[u], -u))[:n]
    last = max(on_disk)
    return best + ([last] if last not in best else [])


def seeds_of(path: Path, label: str) -> list[Policy]:
    """One policy per seed of a checkpoint, labelled `label` (so that candidates stay apart in a table)."""
    seeds = checkpoint_seeds(str(path))
    if len(seeds) < 2:
        raise ConfigError(f"{path} holds {len(seeds)} seed(s): a release's cross-play needs two or more")
    return [load_policy(ZooEntry(f"{label}/s{s}", str(path), label, int(s))) for s in seeds]


def shipped_family(family: str, zoo: Path) -> list[Policy]:
    """The shipped policies labelled `family` (the seeds a release would replace)."""
    entries = [e for e in load_zoo(str(zoo)) if e.algorithm == family]
    if not entries:
        raise ConfigError(f"{zoo} has no policy labelled {family!r}: give --family one of its labels")
    return [load_policy(e) for e in entries]


# ---------------------------------------------------------------------------------------------------------
# PLAYING: one table per question, kept compressed; played only when not there
# ---------------------------------------------------------------------------------------------------------


class Tables:
    """The release's tables in `folder` (`<name>.csv.bz2`), each played once."""

    def __init__(self, folder: Path, say: Any) -> None:
        self.folder, self.say = folder, say
        folder.mkdir(parents=True, exist_ok=True)

    def path(self, name: str) -> Path:
        return self.folder / f"{name}.csv.bz2"

    def get(
        self,
        name: str,
        policies: Sequence[Policy],
        levels: str,
        *,
        episodes: int = 1,
        steps: int = STEPS,
        pairs: str = "all",
    ) -> tuple[EpisodeTable, bool]:
        """(table, played now): read from its file, or played and written."""
        path = self.path(name)
        if path.exists():
            return read_csv(path), False
        self.say(f"playing {name}: {len(policies)} policies on {levels}, {steps}-step episodes ({pairs})")
        config = EvalConfig(levels=levels, episodes=episodes, max_steps=steps, pairs=pairs, games_per_call=1)
        played = crossplay(list(policies), eval_levels("overcooked", levels), config)
        plain = write_csv(played, path.with_suffix(""))  # `name.csv`, then compressed beside it
        path.write_bytes(bz2.compress(plain.read_bytes(), 9))
        plain.unlink()
        return played, True


def xp_parts(tab: EpisodeTable, label: str, levels: str) -> dict[str, PartScore]:
    return part_scores(tab, label, dict(zip(*_names_levels(levels), strict=True)))


def _names_levels(levels: str) -> tuple[tuple[str, ...], list[Any]]:
    from cec.levels.named import resolve_levels

    resolved = resolve_levels(levels)
    return tuple(resolved), list(resolved.values())


def seed_xp(tab: EpisodeTable, label: str) -> list[float]:
    """Each seed's mean cross-play with the other seeds of `label` (the figures a choice averages)."""
    m = _xp_matrix(tab, label)
    off = np.where(np.eye(len(m), dtype=bool), np.nan, m)
    return [float(np.nanmean(row)) if np.any(np.isfinite(row)) else math.nan for row in off]


# ---------------------------------------------------------------------------------------------------------
# THE RELEASE
# ---------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Options:
    run: Path
    prefix: str
    family: str = "cec_teacher"
    candidates: int = 3
    ship: bool = False
    sets: Sets = dataclasses.field(default_factory=Sets)
    steps: int = STEPS
    zoo: Path = SHIPPED_ZOO
    ledger: Path = ledger.LEDGER
    docs: Path = REPO / "docs" / "releases"


def release(opts: Options, say: Any = print) -> dict[str, Any]:
    """The whole release (module docstring); returns the figures the report prints."""
    from cec.paths import safe_name

    safe_name(opts.prefix, "--prefix", fix="give a plain name such as rel21m")
    out = opts.run / "release"
    tables = Tables(out, say)
    sets = opts.sets
    # 1-2. the choice, on validation only
    updates = candidates(opts.run, opts.candidates)
    on_disk = checkpoints_of(opts.run)
    say(f"candidates (best recorded validation cross-play, then the last): updates {updates}")
    figures: dict[str, list[float]] = {}
    valid: dict[int, EpisodeTable] = {}
    for update in updates:
        label = f"{opts.run.name}@{update}"
        policies = seeds_of(on_disk[update], label)
        valid[update] = tables.get(f"validation_u{update}", policies, sets.validation, steps=opts.steps)[0]
        figures[str(update)] = seed_xp(valid[update], label)
    parts = {u: xp_parts(valid[u], f"{opts.run.name}@{u}", sets.validation) for u in updates}
    chosen = int(choose(figures, what=f"{opts.run}: the release's checkpoint (validation cross-play)"))
    label = f"{opts.run.name}@{chosen}"
    seeds = seeds_of(on_disk[chosen], label)
    say(f"chosen on validation: update {chosen}, cross-play {_pm(_headline(parts[chosen]))}")
    choice = {"update": chosen, "checkpoint": str(on_disk[chosen]), "candidates": figures}
    (out / "choice.json").write_text(json.dumps(choice, indent=1) + "\n")
    # 3. what ships now, on the same validation episodes
    incumbent = shipped_family(opts.family, opts.zoo)
    inc_tab, _ = tables.get(f"validation_{opts.family}", incumbent, sets.validation, steps=opts.steps)
    inc_parts = xp_parts(inc_tab, opts.family, sets.validation)
    versus = compare_crossplay(_xp_matrix(valid[chosen], label), _xp_matrix(inc_tab, opts.family))
    exact = None  # the exact test needs the two families' seeds with each other too, and 2 seeds a side
    if len(seeds) >= 2 and len(incumbent) >= 2:
        between = _with(
            tables, f"validation_with_{opts.family}", seeds, incumbent, sets.validation, 1, opts.steps
        )
        pooled = _pooled_matrix(EpisodeTable.concat([valid[chosen], inc_tab, between]), label, opts.family)
        try:
            exact = permutation_crossplay(pooled, len(seeds))
        except ValueError:  # more splits than it enumerates (many seeds): the Welch p only, as cec report
            exact = None
    # 4. the test sets, once each, after the choice
    tests: dict[str, TestScores] = {}
    for name, spec in (("test", sets.test), ("reused_test", sets.reused_test)):
        before = ledger.times_read(spec, opts.ledger)
        tab, played = tables.get(name, seeds, spec, steps=opts.steps)
        if played:
            what = f"{opts.prefix}: {label}'s {len(seeds)} seeds, chosen on validation"
            ledger.record(
                spec, what, f"cec release {opts.run} --prefix {opts.prefix}", _commit(), opts.ledger
            )
        else:
            before -= 1  # the read recorded when this table was played
        tests[name] = TestScores(spec, xp_parts(tab, label, spec), before)
    # 5. beside it
    classic, _ = tables.get("classic", seeds, sets.classic, episodes=CLASSIC_EPISODES, steps=opts.steps)
    proxies = [
        p
        for p in shipped_family("human_proxy", opts.zoo)
        if p.levels and set(p.levels) & set(_names_levels(sets.classic)[0])
    ]
    with_proxies = _with(tables, "with_proxies", seeds, proxies, sets.classic, CLASSIC_EPISODES, opts.steps)
    controls = _controls(on_disk[chosen])
    cook = scripted_policy("cook", name="cook", env=seeds[0].env)
    with_cook = _with(tables, "with_cook", [*seeds, *controls], [cook], sets.validation, 1, opts.steps)
    short = {
        spec: _headline(
            xp_parts(
                tables.get(f"steps{AUTHORS_STEPS}_{name}", seeds, spec, steps=AUTHORS_STEPS)[0], label, spec
            )
        )
        for name, spec in (("validation", sets.validation), ("test", sets.test), ("classic", sets.classic))
    }
    figures_out = {
        "prefix": opts.prefix,
        "run": str(opts.run),
        "chosen": chosen,
        "label": label,
        "seeds": len(seeds),
        "validation": parts[chosen],
        "candidates": {u: _headline(parts[u]) for u in updates},
        "incumbent": inc_parts,
        "versus": versus,
        "exact": exact,
        "tests": tests,
        "classic": xp_parts(classic, label, sets.classic),
        "with_proxies": _partner_means(with_proxies, label, "human_proxy"),
        "with_cook": {lab: _partner_means(with_cook, lab, "cook") for lab in (label, "random_init", "noop")},
        "steps100": short,
        "family": opts.family,
    }
    _plot_record(opts.run, out / "record.png")
    shutil.copyfile(opts.run / "eval" / "record.csv", out / "record.csv")
    (out / "README.md").write_text(report(figures_out))
    say(f"report: {out / 'README.md'}")
    # 7. ship
    if opts.ship:
        ship(opts, seeds, figures_out)
    return figures_out


class TestScores(NamedTuple):
    """A test set's parts and how often the set was read before this release's read."""

    spec: str
    parts: dict[str, PartScore]
    reads_before: int


def _headline(parts: dict[str, PartScore]) -> PartScore:
    """A set's headline part: its generated kitchens, else all of its named ones (the classic five)."""
    return parts["generated"] if "generated" in parts else parts[next(iter(parts))]


def _pm(p: PartScore) -> str:
    return pm(p.xp, p.xp_se)


def _xp_matrix(tab: EpisodeTable, label: str) -> np.ndarray:
    """The seed x seed matrix of `label`'s seeds with each other (per pair, levels averaged)."""
    from cec.evaluation import analysis as an

    own = tab.select((tab.algorithm_a == label) & (tab.algorithm_b == label))
    return an.seed_matrix(an.pair_level_scores(own, sorted(set(own.level.astype(str)))), label).values


def _pooled_matrix(tab: EpisodeTable, label: str, family: str) -> np.ndarray:
    """The seed x seed matrix of `label`'s seeds followed by `family`'s, every pair across the two too
    (levels averaged): what `permutation_crossplay` relabels."""
    from cec.evaluation import analysis as an

    pl = an.pair_level_scores(tab, sorted(set(tab.level.astype(str))))
    idx = [i for a in (label, family) for i, p in enumerate(pl.policies) if p.algorithm == a]
    return an.pair_scores(pl)[np.ix_(idx, idx)]


def _with(
    tables: Tables,
    name: str,
    seeds: Sequence[Policy],
    partners: Sequence[Policy],
    levels: str,
    episodes: int,
    steps: int,
) -> EpisodeTable:
    """Each of `seeds` with each of `partners` (both seats), one table."""
    path = tables.path(name)
    if path.exists():
        return read_csv(path)
    parts = [
        tables.get(
            f"{name}_{i}", [s, *partners], levels, episodes=episodes, steps=steps, pairs=f"with:{s.name}"
        )[0]
        for i, s in enumerate(seeds)
    ]
    whole = EpisodeTable.concat(parts)
    plain = write_csv(whole.select(whole.policy_a != whole.policy_b), path.with_suffix(""))
    path.write_bytes(bz2.compress(plain.read_bytes(), 9))
    plain.unlink()
    for i in range(len(seeds)):
        tables.path(f"{name}_{i}").unlink()
    return read_csv(path)


def _partner_means(tab: EpisodeTable, label: str, partner: str) -> tuple[float, float, int]:
    """(mean, standard error over `label`'s seeds, seeds) of their return with the partners labelled
    `partner` (or named so), per level then over levels."""
    rows = tab.select((tab.algorithm_a == label) & ((tab.algorithm_b == partner) | (tab.policy_b == partner)))
    per_seed = []
    for seed in sorted(set(rows.seed_a.tolist())):
        mine = rows.select(rows.seed_a == seed)
        per_level = [
            float(np.mean(mine.returns[mine.level == lv])) for lv in sorted(set(mine.level.tolist()))
        ]
        per_seed.append(float(np.mean(per_level)))
    return (float(np.mean(per_seed)) if per_seed else math.nan, sem(np.asarray(per_seed)), len(per_seed))


def _controls(checkpoint: Path) -> list[Policy]:
    """The cook's two controls: the recipe's network untrained, and a partner that always stays put."""
    import jax

    config = from_dict(TrainConfig, checkpoints.read_meta(checkpoint)["config"], where="checkpoint config")
    untrained = random_policy(
        "random_init",
        jax.random.PRNGKey(0),
        env=config.env,
        network=config.network_config,
        algorithm="random_init",
    )
    return [untrained, scripted_policy("noop", name="noop", env=config.env, algorithm="noop")]


def _commit() -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True, timeout=10
        )
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _plot_record(run: Path, path: Path) -> None:
    """The training record's validation cross-play (and the other groups) against env steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in read_record(run / "eval" / "record.csv") if r["level_set"] == RECORD_SET]
    fig, ax = plt.subplots(figsize=(7, 4))
    for group in sorted({r["partner_group"] for r in rows}):
        mine = [r for r in rows if r["partner_group"] == group and r["return_mean"] is not None]
        ax.plot(
            [r["env_steps"] / 1e6 for r in mine],
            [r["return_mean"] for r in mine],
            marker="o",
            ms=3,
            label=group,
        )
    ax.set_xlabel("env steps per seed (millions)")
    ax.set_ylabel(f"return per {STEPS}-step episode")
    ax.set_title(f"{run.name}: the evaluator's record on {RECORD_SET} (a fixed quarter of its kitchens)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------------------------------------
# REPORT AND SHIP
# ---------------------------------------------------------------------------------------------------------


def report(f: dict[str, Any]) -> str:
    """RUN/release/README.md from the figures (`release`'s), through the template `templates/release.md`."""
    columns = ["part", "kitchens", "cross-play", "self-play"]

    def parts_table(parts: dict[str, PartScore]) -> str:
        return table(columns, [[k, p.levels, _pm(p), pm(p.sp, p.sp_se)] for k, p in parts.items()])

    v, versus, cook, tests = f["validation"], f["versus"], f["with_cook"], f["tests"]
    handover = next((p for k, p in v.items() if k.startswith("hand-over")), None)
    cands = [[u, _pm(p), "chosen" if u == f["chosen"] else ""] for u, p in f["candidates"].items()]
    return TEMPLATES.fill(
        "release",
        prefix=f["prefix"],
        run=f["run"],
        chosen=str(f["chosen"]),
        seeds=str(f["seeds"]),
        family=f["family"],
        headline=_pm(_headline(v)),
        handover="—" if handover is None else _pm(handover),
        incumbent=_pm(_headline(f["incumbent"])),
        ships="yes" if shippable(f) else "no (below the shipped seeds)",
        diff=f"{num(versus.diff, signed=True)} [{num(versus.ci_low, signed=True)}, "
        f"{num(versus.ci_high, signed=True)}], p {num(versus.p, 3)}",
        exact="—"
        if f["exact"] is None
        else f"p {num(f['exact'].p, 3)} (the smallest it can be: {num(f['exact'].p_min, 3)}; "
        f"{f['exact'].relabellings} relabellings)",
        candidates=table(["update", "validation cross-play", ""], cands),
        validation=parts_table(v),
        incumbent_parts=parts_table(f["incumbent"]),
        test_set=tests["test"].spec,
        test=parts_table(tests["test"].parts),
        test_reads=str(tests["test"].reads_before),
        reused_set=tests["reused_test"].spec,
        reused=parts_table(tests["reused_test"].parts),
        reused_reads=str(tests["reused_test"].reads_before),
        classic=parts_table(f["classic"]),
        proxies=pm(*f["with_proxies"][:2]),
        cook=pm(*cook[f["label"]][:2]),
        cook_untrained=num(cook["random_init"][0]),
        cook_noop=num(cook["noop"][0]),
        steps100=table(
            ["set", "cross-play", "self-play"],
            [[k, _pm(p), pm(p.sp, p.sp_se)] for k, p in f["steps100"].items()],
        ),
    )


def shippable(f: dict[str, Any]) -> bool:
    """The ship rule: the release's validation cross-play at least the shipped seeds' on the same episodes."""
    return bool(_headline(f["validation"]).xp >= _headline(f["incumbent"]).xp)


def ship(opts: Options, seeds: Sequence[Policy], f: dict[str, Any]) -> None:
    """The release into the shipped zoo in place of the family's seeds, if not worse on validation."""
    ours, theirs = _headline(f["validation"]).xp, _headline(f["incumbent"]).xp
    if not shippable(f):
        raise ConfigError(
            f"not shipped: the release's validation cross-play {num(ours)} is below the shipped "
            f"{opts.family} seeds' {num(theirs)} on the same episodes; the report: {opts.run / 'release'}"
        )
    meta = checkpoints.read_meta(Path(str(checkpoints_of(opts.run)[f["chosen"]])))
    shipped_dir = opts.zoo.parent
    doc = yaml.safe_load(opts.zoo.read_text())
    kept = [e for e in doc["policies"] if e.get("algorithm") != opts.family]
    added = []
    for policy in seeds:
        name = f"{opts.prefix}-s{policy.seed}"
        as_family = dataclasses.replace(policy, name=name, algorithm=opts.family)
        path = shipped_dir / name
        save_policy(
            as_family,
            path,
            config=meta["config"],
            env_steps=int(meta["env_steps"]),
            update=int(meta["update"]),
            code_version=checkpoints.code_version(),
        )
        added.append(
            {
                "name": name,
                "algorithm": opts.family,
                "seed": int(policy.seed),
                "checkpoint": name,
                "env": policy.env.name,
                "layout": policy.env.levels,
                "env_steps": int(meta["env_steps"]),
                "sha256": checkpoints.read_meta(path)["sha256"],
            }
        )
    gone = [e for e in doc["policies"] if e.get("algorithm") == opts.family]
    doc["policies"] = kept + added
    tmp = opts.zoo.with_name(opts.zoo.name + ".tmp")
    header = "".join(line + "\n" for line in opts.zoo.read_text().splitlines() if line.startswith("#"))
    tmp.write_text(header + yaml.safe_dump(doc, sort_keys=False))
    tmp.replace(opts.zoo)
    for e in gone:  # the replaced seeds' folders, where they are plain folders of the shipped zoo's own
        folder = shipped_dir / str(e.get("checkpoint", ""))
        if e.get("checkpoint") and folder.parent == shipped_dir and folder.is_dir():
            shutil.rmtree(folder)
    docs = opts.docs / opts.prefix
    docs.mkdir(parents=True, exist_ok=True)
    for p in (opts.run / "release").iterdir():
        if p.suffix in (".md", ".png", ".bz2", ".csv", ".json"):
            shutil.copyfile(p, docs / p.name)
    print(
        f"shipped {len(added)} seeds as {opts.family} ({', '.join(a['name'] for a in added)}) in place of "
        f"{', '.join(e['name'] for e in gone)}; the report in {docs}",
        file=sys.stderr,
    )


# ---------------------------------------------------------------------------------------------------------
# COMMAND LINE
# ---------------------------------------------------------------------------------------------------------


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("release", help="choose a run's release on validation, test it once, report, ship")
    p.add_argument("run", help="the run directory (cec up's, e.g. runs/up-release)")
    p.add_argument("--prefix", required=True, help="the release's name: shipped seeds are <prefix>-s<seed>")
    p.add_argument(
        "--family", default="cec_teacher", help="the shipped label it is compared with and replaces"
    )
    p.add_argument(
        "--candidates", type=int, default=3, help="recorded best checkpoints played on all validation"
    )
    p.add_argument("--ship", action="store_true", help="ship it if not worse on validation than what ships")
    sets = p.add_argument_group("what it plays (level specs, as cec eval --levels; defaults: the README's)")
    for field in dataclasses.fields(Sets):
        flag = "--" + field.name.replace("_", "-")
        sets.add_argument(flag, dest=field.name, default=field.default, help=f"default {field.default}")
    p.add_argument("--max-steps", type=int, default=STEPS, help=f"episode length (default {STEPS})")
    p.add_argument("--zoo", default=str(SHIPPED_ZOO), help="the shipped zoo it is compared with and ships to")
    p.add_argument("--ledger", default=str(ledger.LEDGER), help="the ledger of test-set reads")
    p.add_argument(
        "--docs", default=str(REPO / "docs" / "releases"), help="where a shipped release's report goes"
    )
    p.set_defaults(func=_cmd_release)


def _cmd_release(args: argparse.Namespace) -> int:
    if args.candidates < 1:
        raise ConfigError(f"--candidates must be >= 1, got {args.candidates}")
    run = Path(args.run)
    if not run.is_dir():
        raise ConfigError(f"run directory {str(run)!r} does not exist")
    if not 1 <= args.max_steps <= 100_000:
        raise ConfigError(f"--max-steps must be in 1..100000, got {args.max_steps}")
    sets = Sets(**{f.name: getattr(args, f.name) for f in dataclasses.fields(Sets)})
    for field in dataclasses.fields(Sets):  # every spec resolved before anything is played
        _names_levels(getattr(sets, field.name))
    opts = Options(
        run,
        args.prefix,
        args.family,
        args.candidates,
        args.ship,
        sets,
        args.max_steps,
        Path(args.zoo),
        Path(args.ledger),
        Path(args.docs),
    )
    release(opts, say=lambda m: print(m, file=sys.stderr, flush=True))
    return 0
