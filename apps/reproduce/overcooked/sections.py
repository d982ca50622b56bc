"""The report's sections after its tests (this paper's own part): per kitchen, collisions and episodes
without a soup, the cross-algorithm matrices, held-out play by training kitchen, the cross-play learning
curves, whether the single-kitchen runs levelled off, and the baselines without a soup in their kitchen.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import yaml

from apps.machine import duration
from apps.reproduce.overcooked.evaluate import level_spec
from apps.reproduce.overcooked.modes import (
    ALGORITHMS,
    EVAL_STEPS,
    GENERALISTS,
    LEVEL_SETS,
    SELF_PLAY,
    TITLES,
    UNTRAINED,
    Mode,
)
from apps.reproduce.overcooked.plan import run_name
from cec.agents.zoo import HUMAN_PROXY
from cec.evaluation import markdown as md
from cec.evaluation.curves import metrics_file
from cec.evaluation.markdown import NONE, Templates, num, pm, table_lines

if TYPE_CHECKING:
    from cec.evaluation.milestones import MilestonePoint
    from cec.evaluation.results import EpisodeTable

#: The report's templates (`templates/*.md`), this module's and `report`'s.
TEMPLATES = Templates(Path(__file__).parent / "templates")


def analysis_lines(
    mode: Mode, table: EpisodeTable, runs: Path, controls: EpisodeTable | None = None
) -> list[str]:
    """The sections after the tests: per kitchen (`episode_lines`, with the `controls`' table), the
    cross-algorithm matrices, held-out play by training kitchen, whether the single-kitchen runs levelled
    off, and the baselines without a soup in their own kitchen."""
    return [
        *episode_lines(mode, table, controls), *cross_algorithm_lines(mode, table),
        *heldout_kitchen_lines(mode, table), *plateau_lines(mode, runs), *failing_lines(mode, table, runs),
    ]  # fmt: skip


def episode_lines(mode: Mode, table: EpisodeTable, controls: EpisodeTable | None = None) -> list[str]:
    """The per-kitchen view the seed-level tables average over: per algorithm, cross-play (two different
    seeds) and self-play in each classic kitchen and over the held-out ones, then per level set the
    collisions per episode, the share of cross-play episodes without a soup and the collisions per soup
    (with the untrained network's cross-play from `controls`, the controls' table, beside them). Means over
    episodes (descriptive; the seed-level tests are above)."""
    xp, sp = _xp_sp(table)
    held = _held_out(mode, table)
    columns = [(k, table.level == k) for k in mode.kitchens] + [("held-out", held)]
    algos = [a for a in ALGORITHMS if np.any(table.algorithm_a == a)]
    kitchens = [k for k in mode.kitchens if any(_of_kitchen(table.policy_a[held], a, k).any() for a in algos)]

    def mean(values: np.ndarray, mask: np.ndarray, fmt: str = "{:.1f}") -> str:
        return fmt.format(float(values[mask].mean())) if mask.any() else NONE

    rows = []
    for algo in algos:
        mine = table.algorithm_a == algo
        cells = (
            f"{mean(table.returns, mine & xp & m)} ({mean(table.returns, mine & sp & m)})" for _, m in columns
        )
        rows.append([TITLES[algo], *cells])
    who = [(TITLES[a], table, a) for a in algos]
    if controls is not None and np.any(controls.algorithm_a == UNTRAINED):
        who.append((TITLES[UNTRAINED], controls, UNTRAINED))
    collisions = []
    for title, t, algo in who:
        t_xp, t_held = _xp_sp(t)[0], _held_out(mode, t)
        sets = [(t.algorithm_a == algo) & t_xp & m for m in (~t_held, t_held)]
        coll = [mean(t.collisions, m) for m in sets]
        none = [mean((t.deliveries == 0).astype(float), m, "{:.0%}") for m in sets]
        per_soup = [_per_soup(t.collisions[m].sum(), t.deliveries[m].sum()) for m in sets]
        collisions.append([title, *coll, *none, *per_soup])
    return TEMPLATES.lines(
        "per_kitchen",
        eval_steps=EVAL_STEPS,
        kitchens=", ".join(kitchens or ["none"]),
        returns=md.table(["algorithm", *(k for k, _ in columns)], rows),
        collisions=md.table(COLLISION_HEAD, collisions),
    )


COLLISION_HEAD = (
    "algorithm", "collisions, classic", "collisions, held-out", "no soup, classic", "no soup, held-out",
    "per soup, classic", "per soup, held-out",
)  # fmt: skip


def _per_soup(collisions: float, soups: float) -> str:
    if not soups:
        return NONE
    ratio = float(collisions) / float(soups)
    return f"{ratio:.1f}" if ratio < 1000 else f"{ratio:,.0f}"


def _xp_sp(table: EpisodeTable) -> tuple[np.ndarray, np.ndarray]:
    """Rows of cross-play (two different seeds of one algorithm) and of self-play."""
    same = table.algorithm_a == table.algorithm_b
    return same & (table.seed_a != table.seed_b), same & (table.seed_a == table.seed_b)


def _held_out(mode: Mode, table: EpisodeTable) -> np.ndarray:
    """Rows played on the mode's held-out kitchens."""
    return np.isin(table.level, level_spec(mode, "heldout").split(","))


def agent_games(table: EpisodeTable, *, with_proxies: bool = True) -> EpisodeTable:
    """The games of the trained agents with each other (and with the human proxies): the table without the
    cook and the controls."""
    who = (*ALGORITHMS, HUMAN_PROXY) if with_proxies else ALGORITHMS
    return table.select(np.isin(table.algorithm_a, who) & np.isin(table.algorithm_b, who))


def _of_kitchen(names: np.ndarray, algo: str, kitchen: str) -> np.ndarray:
    """Which policy names are `algo`'s agents of `kitchen` (the zoo's run names: `ALGO_KITCHEN-sSEED`)."""
    return np.char.startswith(names.astype(str), f"{run_name(algo, kitchen)}-s")


def curve_points(curves: EpisodeTable | None) -> tuple[list[MilestonePoint], int]:
    """The cross-play learning curves' points (`cec.evaluation.milestones.milestone_points`) of
    `cached_curves`' games, and the held-out kitchens they were played on (none: no games)."""
    from cec.evaluation.milestones import milestone_points

    if curves is None or not len(curves):
        return [], 0
    return milestone_points(curves), len(set(curves.level))


def curve_lines(points: Sequence[MilestonePoint], kitchens: int) -> list[str]:
    """The cross-play learning curves (`curve_points`) as a table: each checkpoint's cross-play and
    self-play on the held-out kitchens."""
    if not points:
        missing = "Not measured: the work folder has neither the runs' milestone checkpoints nor their games."
        return ["## Cross-play learning curves (held-out kitchens)", "", missing, ""]
    rows = [
        [TITLES.get(p.name, p.name), f"{p.env_steps:,}", len(p.seeds), pm(p.xp, p.xp_se), pm(p.sp, p.sp_se)]
        for p in points
    ]
    head = ["algorithm", "env steps per seed", "seeds", "cross-play", "self-play"]
    return TEMPLATES.lines("curves", kitchens=kitchens, eval_steps=EVAL_STEPS, table=md.table(head, rows))


def cross_algorithm_lines(mode: Mode, table: EpisodeTable) -> list[str]:
    """Per level set the cross-algorithm matrix (`cec.evaluation.analysis.algorithm_matrix`): cell (A, B)
    the mean team return of the pairs of an A agent and a different B agent (on the diagonal: cross-play),
    each pair's score the mean over the kitchens both play (the paper's ad-hoc teamplay heatmaps)."""
    from cec.evaluation import analysis as an

    agents = agent_games(table, with_proxies=False)
    blocks = []
    for level_set in LEVEL_SETS:
        m = an.algorithm_matrix(an.pair_level_scores(agents, level_spec(mode, level_set).split(",")))
        if not m.labels:
            continue
        titles = [TITLES.get(a, a) for a in m.labels]
        rows = ([title, *(num(v) for v in values)] for title, values in zip(titles, m.values, strict=True))
        lines = [f"**{level_set}**", "", *table_lines(["", *titles], rows, tight=True)]
        off = m.values[~np.eye(len(m.labels), dtype=bool)]
        if off.size and np.isnan(off).all():
            lines += ["", "No two algorithms met in this table (it was played before every agent met every "
                      "other): the cells off the diagonal are empty."]  # fmt: skip
        blocks.append("\n".join(lines))
    return TEMPLATES.lines("cross_algorithm", matrices="\n\n".join(blocks))


def heldout_kitchen_lines(mode: Mode, table: EpisodeTable) -> list[str]:
    """Held-out cross-play (self-play) of each single-kitchen algorithm by the kitchen its agents trained
    on: which kitchens' agents carry anything to kitchens they never saw."""
    xp, sp = _xp_sp(table)
    held = _held_out(mode, table)
    algos = [a for a in ALGORITHMS if a not in GENERALISTS and np.any(table.algorithm_a == a)]
    if not algos:
        return []
    rows = []
    for algo in algos:
        cells = []
        for k in mode.kitchens:
            mine = held & _of_kitchen(table.policy_a, algo, k) & _of_kitchen(table.policy_b, algo, k)
            cells.append(
                f"{table.returns[mine & xp].mean():.1f} ({table.returns[mine & sp].mean():.1f})"
                if (mine & xp).any() and (mine & sp).any() else NONE
            )  # fmt: skip
        rows.append([TITLES[algo], *cells])
    return TEMPLATES.lines(
        "heldout", eval_steps=EVAL_STEPS, table=md.table(["algorithm", *mode.kitchens], rows)
    )


def _kitchen_runs(runs: Path, algo: str, kitchen: str) -> list[Path]:
    """`algo`'s run directories on `kitchen` under `runs` (one per spec entry)."""
    return sorted(runs.glob(f"{run_name(algo, kitchen)}-s*"))


def _curves(runs: Path, algo: str, kitchen: str, column: str) -> list[np.ndarray]:
    """Per seed of `algo`'s runs on `kitchen` under `runs`, `column` of its `metrics.csv` by update."""
    from cec.evaluation.curves import read_curve

    runs_k = [r for r in _kitchen_runs(runs, algo, kitchen) if metrics_file(r).is_file()]
    return [v for r in runs_k for _, v in read_curve(r, column).values() if len(v)]


def _episode_steps(runs: Path, algo: str, kitchens: Sequence[str]) -> str:
    """The training episode length of `algo`'s runs on `kitchens` under `runs`, as each run's `config.yaml`
    recorded it ('128', or '128/400' where they differ; '—' when no run has its config there)."""
    configs = [r / "config.yaml" for k in kitchens for r in _kitchen_runs(runs, algo, k)]
    steps = {
        int(yaml.safe_load(c.read_text())["env"]["overcooked"]["max_steps"]) for c in configs if c.is_file()
    }
    return "/".join(str(s) for s in sorted(steps)) or "—"


#: A single-kitchen group levelled off when its training return rose by at most this share of its final
#: value over the last quarter of its run (issue 60's criterion; a return flat at 0 counts as levelled).
PLATEAU_SHARE = 0.05


class _Plateau(NamedTuple):
    """One single-kitchen group's end of training (means over its seeds)."""

    last: float  # team return per training episode, the last 10 updates
    rise: float  # its rise over the last quarter of the run
    before: float  # its rise over the quarter before that
    env_steps: int  # env steps per seed at its last update
    seeds: int
    seconds_per_seed: float  # training time per seed its metrics record (`pipeline.train_seconds`)

    @property
    def levelled(self) -> bool:
        return self.rise <= PLATEAU_SHARE * abs(self.last)

    @property
    def quarters(self) -> int | None:
        """`plateau_quarters` of this group's returns."""
        return plateau_quarters(self.last - self.rise - self.before, self.last - self.rise, self.last)


#: The longest run `plateau_quarters` projects, in quarters of the present one (16x it).
MAX_QUARTERS = 64


def plateau_quarters(half: float, three_quarters: float, last: float) -> int | None:
    """How long a run would have to be, in quarters of the present one (4: it is long enough), for its own
    last quarter to rise by at most `PLATEAU_SHARE` of its return, from the training return at a half, three
    quarters and all of the present run: an exponential approach R(t) = A - B rho^t (t in quarters) through
    those three points, rho the ratio of the last quarter's rise to the one before. None where the rise is
    not slowing (rho >= 1, or no rise before the last quarter) or the projection passes `MAX_QUARTERS`. An
    extrapolation of the training return: a longer run also stretches the recipe's LR schedule."""
    rise, before = last - three_quarters, three_quarters - half
    if rise <= PLATEAU_SHARE * abs(last):
        return 4
    if before <= 0 or rise >= before:
        return None
    rho = rise / before
    b = rise / (rho**3 * (1 - rho))  # R(4) - R(3) = B rho^3 (1 - rho)
    a = last + b * rho**4
    for q in range(5, MAX_QUARTERS + 1):  # a run of q quarters: its last quarter spans 0.75q .. q
        if b * (rho ** (0.75 * q) - rho**q) <= PLATEAU_SHARE * abs(a - b * rho**q):
            return q
    return None


def _plateau(runs: Path, algo: str, kitchen: str) -> _Plateau | None:
    """`algo`'s group on `kitchen` from its runs' metrics under `runs`; None without 4 updates."""
    from apps.reproduce.pipeline import read_metrics, train_seconds
    from cec.evaluation.curves import trailing_mean

    smooth = [trailing_mean(v, 10) for v in _curves(runs, algo, kitchen, "mean_return") if len(v) >= 4]
    if not smooth:
        return None
    half, three_quarters, last = np.mean(
        [(m[len(m) // 2 - 1], m[(3 * len(m)) // 4 - 1], m[-1]) for m in smooth], axis=0
    )
    rows = [read_metrics(r) for r in _kitchen_runs(runs, algo, kitchen)]
    seeds = sum(len({r["seed"] for r in rr}) for rr in rows)
    steps = max((int(r["env_steps"]) for rr in rows for r in rr), default=0)
    seconds = sum(train_seconds(rr) for rr in rows) / max(seeds, 1)
    rise, before = float(last - three_quarters), float(three_quarters - half)
    return _Plateau(float(last), rise, before, steps, seeds, seconds)


def plateau_lines(mode: Mode, runs: Path) -> list[str]:
    """Whether each single-kitchen algorithm's training had levelled off: its team return per training
    episode over the last 10 updates, how much it rose over the last quarter of the run (the mean over
    seeds; `metrics.csv` of its runs under `runs`) and the verdict by `PLATEAU_SHARE`; then a line per
    group that had not, with where it stopped, how much longer its run would have to be by
    `plateau_quarters` and what the rest of its training costs."""
    algos = [a for a in ALGORITHMS if a not in GENERALISTS]
    groups = {(a, k): g for a in algos for k in mode.kitchens if (g := _plateau(runs, a, k)) is not None}
    if not groups:
        return []
    rising = [(a, k, g) for (a, k), g in groups.items() if not g.levelled]

    def cell(a: str, k: str) -> str:
        g = groups.get((a, k))
        return NONE if g is None else f"{g.last:.1f} ({g.rise:+.1f}) {'yes' if g.levelled else 'no'}"

    def rest(g: _Plateau) -> float:  # seconds per seed from the present end to the projected plateau
        return g.seconds_per_seed * ((g.quarters or 4) / 4 - 1)

    verdict = f"{len(groups) - len(rising)} of {len(groups)} groups levelled off."
    if rising:
        projected = [g for _, _, g in rising if g.quarters is not None]
        quarter = duration(sum(g.seconds_per_seed / 4 * g.seeds for _, _, g in rising))
        verdict += (
            " The others stopped, still rising, at the env steps their mode gives a single-kitchen run "
            "(`steps` in `apps/reproduce/overcooked/modes.py`); none was trained on to a plateau. Where a "
            "group's rise per quarter was shrinking, an exponential approach through its return at a half, "
            "three quarters and all of its run projects the length at which it would level off by the same "
            "test (an extrapolation: a longer run also stretches the recipe's LR schedule). "
        )
        if projected:
            cost = duration(sum(rest(g) * g.seeds for g in projected))
            verdict += (
                f"Training the {len(projected)} projected group(s) on to it, every seed, costs about {cost} "
                f"of the machine that trained them; another quarter for all {len(rising)}, about {quarter}:"
            )
        else:
            verdict += f"Another quarter of training for all of them, every seed, costs about {quarter}:"

    def still(a: str, k: str, g: _Plateau) -> str:
        line = (
            f"- {TITLES[a]}, {k}: +{g.rise:.1f} over the last quarter, {g.rise / abs(g.last):.0%} of its "
            f"{g.last:.1f}, at {g.env_steps:,} env steps per seed; "
        )
        if g.quarters is None:
            return line + (
                f"its rise not slowing (+{g.before:.1f} the quarter before), no length projected; another "
                f"quarter costs {g.seconds_per_seed / 4 / 60:.1f} min per seed"
            )
        return line + (
            f"projected to level off at {g.quarters / 4:g}x its run, the rest costing "
            f"{rest(g) / 60:.1f} min per seed"
        )

    head = ["algorithm", "training episode (steps)", *mode.kitchens]
    rows = [
        [TITLES[a], _episode_steps(runs, a, mode.kitchens), *(cell(a, k) for k in mode.kitchens)]
        for a in algos
    ]
    return TEMPLATES.lines(
        "plateau", share=f"{PLATEAU_SHARE:.0%}", table=md.table(head, rows),
        verdict="\n".join([verdict, *([""] if rising else []), *(still(a, k, g) for a, k, g in rising)]),
    )  # fmt: skip


FAILING_HEAD = (
    "algorithm", "kitchen", "self-play", "cross-play", "training episode (steps)",
    "training return, first → last", "shaped, last", "reading",
)  # fmt: skip


def failing_lines(mode: Mode, table: EpisodeTable, runs: Path) -> list[str]:
    """Every single-kitchen algorithm and kitchen whose self-play there delivers nothing, with what its
    training recorded (`metrics.csv` of its runs under `runs`): the team return per training episode with
    its training partners at the first update and over the last 10, the shaped return, and the reading
    those numbers allow."""
    from cec.evaluation.curves import trailing_mean

    xp, sp = _xp_sp(table)
    rows: list[list[str]] = []
    for algo in (a for a in ALGORITHMS if a not in GENERALISTS):
        for k in mode.kitchens:
            own = (table.algorithm_a == algo) & (table.level == k)
            if not (own & sp).any() or table.returns[own & sp].mean() > 0:
                continue
            curves = {c: _curves(runs, algo, k, c) for c in ("mean_return", "mean_shaped_return")}
            if not curves["mean_return"]:
                rows.append([TITLES[algo], k, "0.0", NONE, NONE, NONE, NONE,
                             "its training metrics are not in the work folder"])  # fmt: skip
                continue
            first = float(np.mean([v[0] for v in curves["mean_return"]]))
            last, shaped = (float(np.mean([trailing_mean(v, 10)[-1] for v in curves[c]])) for c in curves)
            if last < 1.0:
                reading = "no soup in training either: it learned the shaped steps only, not to deliver"
            elif algo in SELF_PLAY:
                reading = "it delivered in its training episodes (with itself), not in these"
            elif first >= last / 2:
                reading = (
                    f"its training partners delivered from its first update ({first:.1f}): it scored with "
                    "them, not by itself"
                )
            else:
                reading = "it learned to deliver with its training partners, but not with a copy of itself"
            xp_k = num(float(table.returns[own & xp].mean())) if (own & xp).any() else NONE
            trained = f"{first:.1f} → {last:.1f}"
            rows.append([TITLES[algo], k, "0.0", xp_k, _episode_steps(runs, algo, [k]), trained, num(shaped),
                         reading])  # fmt: skip
    if not rows:
        return ["## Baselines in their own kitchen", "", "Every single-kitchen algorithm delivers in "
                "self-play in its own kitchen (self-play > 0 in each).", ""]  # fmt: skip
    return TEMPLATES.lines("failing", table=md.table(FAILING_HEAD, rows))
