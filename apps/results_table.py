"""`cec results SPEC [--per-kitchen]`: the README's results table, computed from the release tables a spec
file names (every figure from the episode tables, none typed by hand).

    cec results docs/results.yaml                 # one row per shipped partner set: the README's table
    cec results docs/results.yaml --per-kitchen   # each classic kitchen, the scripted cook beside them

The spec (`docs/results.yaml`) lists the shipped partner sets: how to play each, what it is in plain words,
its release page and the tables it was evaluated in (paths relative to the spec file). Figures, team return
per 400-step episode:

- **with the test human proxies**: each seed with the `hp_<kitchen>` proxy of each classic kitchen (people
  of the published human-human test games; they never met the agents nor a teacher), mean over episodes
  per kitchen, over kitchens per seed, then over seeds ± the standard error over seeds;
- **with each other**: cross-play of the set's seeds (each pair of two different seeds, both seats; the
  mean over pairs ± the jackknife standard error over seeds, `cec.evaluation.stats.crossplay_estimate`) on
  the test set's generated kitchens (`test:`), or, for agents fine-tuned in one kitchen each (`kitchens:`),
  each in its own kitchen, averaged over the five with seeds matched by seed number;
- a scripted partner (`scripted: true`, the cook) has one policy: with itself, no standard error.

The product reads only what the spec names (DESIGN rule 15: it names no path of the record itself).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

if TYPE_CHECKING:
    from cec.evaluation.results import EpisodeTable

#: The classic kitchens in the order the release tables print them.
KITCHENS = ("cramped_room", "asymm_advantages", "coord_ring", "forced_coord", "counter_circuit")
PROXY = "human_proxy"
#: Kitchen names of a generated evaluation set (`cec.levels.kinds.validation_parts`' headline part).
GENERATED = ("generated_", "test_", "test2_")


@dataclasses.dataclass(frozen=True)
class PartnerSet:
    """One shipped partner set and the tables that evaluated it (paths relative to the spec file)."""

    partner: str  # the shipped label: `cec play serve --partner PARTNER`
    what: str  # what it is, in plain words (Markdown)
    release: str = ""  # its release page (or the report that prints its figures)
    link_text: str = "release"  # the words of the link to it
    play: str = ""  # the command to play it (default `cec play serve --partner PARTNER`)
    label: str = ""  # how the tables label its agents (default: `partner`)
    scripted: bool = False  # one scripted policy (the cook): "with itself", no seeds
    test: str = ""  # its seeds with each other on a test set (generated kitchens named test_*/test2_*)
    classic: str = ""  # its seeds with each other on the classic five
    proxies: str = ""  # its seeds with the human proxies on the classic five
    kitchens: str = ""  # a folder of one table per classic kitchen (<kitchen>.csv or .csv.bz2)
    validation: str = ""  # a scripted partner with itself on the validation kitchens


@dataclasses.dataclass(frozen=True)
class Spec:
    sets: tuple[PartnerSet, ...]


class Score(NamedTuple):
    mean: float
    se: float  # NaN where there is one policy


def load_spec(path: Path) -> tuple[Spec, Path]:
    """The spec and the folder its paths are relative to."""
    import yaml

    from cec.config import ConfigError, from_dict

    try:
        data = yaml.safe_load(path.read_text())
    except OSError as err:
        raise ConfigError(f"cannot read the results spec {path}: {err.strerror}") from None
    return from_dict(Spec, data, where=str(path)), path.resolve().parent


def _read(base: Path, name: str) -> EpisodeTable:
    from cec.evaluation.results import read_csv

    return read_csv(base / name)


def _kitchen_tables(base: Path, folder: str) -> EpisodeTable:
    from cec.config import ConfigError
    from cec.evaluation.results import EpisodeTable, read_csv

    tables = []
    for kitchen in KITCHENS:
        found = [base / folder / f"{kitchen}.csv{ext}" for ext in ("", ".bz2", ".gz")]
        path = next((p for p in found if p.exists()), None)
        if path is None:
            raise ConfigError(f"{base / folder} has no table for {kitchen} ({kitchen}.csv or .csv.bz2)")
        tables.append(read_csv(path))
    return EpisodeTable.concat(tables)


def crossplay(table: EpisodeTable, label: str, levels: list[str]) -> Score:
    """`label`'s seeds with each other on `levels` (the mean over pairs, jackknife SE over seeds)."""
    from cec.evaluation import analysis as an
    from cec.evaluation.stats import crossplay_estimate

    own = table.select((table.algorithm_a == label) & (table.algorithm_b == label))
    estimate = crossplay_estimate(an.seed_matrix(an.pair_level_scores(own, levels), label).values)
    return Score(estimate.mean, estimate.se)


def with_partner(table: EpisodeTable, label: str, partner: str, levels: list[str] | None = None) -> Score:
    """`label`'s seeds with the policies labelled `partner`, either seat: per seed the mean over its
    episodes in each level, then over levels; the mean over seeds ± the SE over them."""
    import numpy as np

    from cec.evaluation.stats import sem

    ours_a = (table.algorithm_a == label) & (table.algorithm_b == partner)
    ours_b = (table.algorithm_b == label) & (table.algorithm_a == partner)
    keep = ours_a | ours_b
    if levels is not None:
        keep &= np.isin(table.level, levels)
    seeds = np.where(ours_a, table.seed_a, table.seed_b)[keep]
    level, value = table.level[keep], table.returns[keep]
    per_seed = []
    for seed in sorted(set(seeds.tolist())):
        mine = seeds == seed
        per_seed.append(np.mean([value[mine & (level == lv)].mean() for lv in sorted(set(level[mine]))]))
    return Score(float(np.mean(per_seed)) if per_seed else math.nan, sem(np.asarray(per_seed)))


def with_itself(table: EpisodeTable, name: str, levels: list[str]) -> Score:
    """A single policy (`name`, as its policy is named) with itself: per level, then over `levels`."""
    import numpy as np

    own = table.select((table.policy_a == name) & (table.policy_b == name))
    means = [float(own.returns[own.level == lv].mean()) for lv in levels if np.any(own.level == lv)]
    return Score(float(np.mean(means)) if means else math.nan, math.nan)


class Figures(NamedTuple):
    """What the tables give of one set: with the proxies and with each other, over the five and each."""

    proxies: Score
    together: Score
    where: str  # where `together` was played, in words
    proxies_by_kitchen: dict[str, Score]
    together_by_kitchen: dict[str, Score]
    together_five: Score  # with each other (or itself) over the classic five


def figures(s: PartnerSet, base: Path) -> Figures:
    from cec.config import ConfigError

    label = s.label or s.partner
    kitchens = list(KITCHENS)
    if s.kitchens:  # one table per classic kitchen: everything from them
        tab = _kitchen_tables(base, s.kitchens)
        proxy_tab = classic_tab = tab
    elif s.proxies and s.classic:
        proxy_tab, classic_tab = _read(base, s.proxies), _read(base, s.classic)
    else:
        raise ConfigError(f"{s.partner}: give `kitchens:`, or `proxies:` and `classic:`")
    proxies = with_partner(proxy_tab, label, PROXY, kitchens)
    proxies_by = {k: with_partner(proxy_tab, label, PROXY, [k]) for k in kitchens}
    if s.scripted:
        by = {k: with_itself(classic_tab, label, [k]) for k in kitchens}
        five = with_itself(classic_tab, label, kitchens)
        if not s.validation:
            raise ConfigError(f"{s.partner}: a scripted partner needs `validation:` (with itself there)")
        val = _read(base, s.validation)
        names = sorted({n for n in set(val.level.tolist()) if n.startswith(GENERATED)})
        return Figures(proxies, with_itself(val, label, names), "validation", proxies_by, by, five)
    by = {k: crossplay(classic_tab, label, [k]) for k in kitchens}
    five = crossplay(classic_tab, label, kitchens)
    if s.test:
        test = _read(base, s.test)
        names = sorted({n for n in set(test.level.tolist()) if n.startswith(GENERATED)})
        return Figures(proxies, crossplay(test, label, names), f"test:{len(names)}", proxies_by, by, five)
    return Figures(proxies, five, "own kitchen", proxies_by, by, five)


def _together_cell(s: PartnerSet, f: Figures) -> str:
    from cec.evaluation.markdown import pm

    if s.scripted:
        return (
            f"with itself: {pm(*f.together)} on the 100 validation kitchens, {pm(*f.together_five)} "
            "in the classic five (not played on the test set)"
        )
    if f.where.startswith("test:"):
        return f"{pm(*f.together)} on the test set's {f.where[5:]} generated kitchens"
    return f"{pm(*f.together)}, each in its own classic kitchen (the five)"


def headline(spec: Spec, base: Path, relative_to: Path) -> str:
    """The README's table: one row per set, the learned sets by their figure with the proxies (highest
    first), then the scripted ones."""
    from cec.evaluation.markdown import pm, table

    rows = []
    for s in spec.sets:
        f = figures(s, base)
        play = s.play or f"cec play serve --partner {s.partner}"
        link = f"[{s.link_text}]({_link(base, s.release, relative_to)})" if s.release else ""
        proxies = pm(*f.proxies)
        rows.append((s.scripted, -f.proxies.mean, [f"`{play}`", s.what, proxies, _together_cell(s, f), link]))
    rows.sort(key=lambda r: (r[0], r[1]))
    header = [
        "play it",
        "what it is",
        "with the test human proxies, classic five (never met it or a teacher)",
        "with each other: seeds that never trained together",
        "report",
    ]
    return table(header, [r[2] for r in rows])


def per_kitchen(spec: Spec, base: Path) -> str:
    """Each classic kitchen: every set with each other (or itself) / with the kitchen's test proxy."""
    from cec.evaluation.markdown import num, table
    from cec.levels.classic import CLASSIC_NAMES

    figs = [(s, figures(s, base)) for s in spec.sets]

    def cell(together: Score, proxy: Score) -> str:
        return f"{num(together.mean)} / {num(proxy.mean)}"

    header = [
        "with each other (the cook: itself) / with the test proxy",
        *(f"`{s.partner}`" for s, _ in figs),
    ]
    rows = [
        [CLASSIC_NAMES[k], *(cell(f.together_by_kitchen[k], f.proxies_by_kitchen[k]) for _, f in figs)]
        for k in KITCHENS
    ]
    rows.append(["the five", *(cell(f.together_five, f.proxies) for _, f in figs)])
    return table(header, rows)


def _link(base: Path, target: str, relative_to: Path) -> str:
    return Path(os.path.relpath((base / target).resolve(), relative_to.resolve())).as_posix()


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "results", help="the README's results table, computed from the release tables a spec file names"
    )
    p.add_argument("spec", help="the spec of the shipped partner sets and their tables (docs/results.yaml)")
    p.add_argument(
        "--per-kitchen", action="store_true", help="each classic kitchen instead (the scripted cook beside)"
    )
    p.add_argument(
        "--relative-to", default=".", help="the folder the printed links are relative to (default: here)"
    )
    p.set_defaults(func=_cmd_results)


def _cmd_results(args: argparse.Namespace) -> int:
    spec, base = load_spec(Path(args.spec))
    text = per_kitchen(spec, base) if args.per_kitchen else headline(spec, base, Path(args.relative_to))
    sys.stdout.write(text + "\n")
    return 0
