"""The cross-play of `cec reproduce overcooked`: who meets whom on which kitchens (`lineups`), the agents'
games with the cook and the human proxies line-up by line-up (`part_jobs`: each played once its agents
are trained, `play_ready`, and assembled, `cached_evaluation`), the controls' and the learning curves'
games, each cached while what it depends on is unchanged (`pipeline.cached_table`), and how many episodes
and line-ups that is (`planned_episodes`, `played_lineups`, for `--plan`).
"""

from __future__ import annotations

import dataclasses
import functools
import io
import json
import re
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from apps.machine import machine_info
from apps.reproduce import pipeline
from apps.reproduce.overcooked.modes import (
    ALGORITHMS,
    AUTHORS_STEPS,
    COOK,
    EVAL_STEPS,
    GENERALISTS,
    KITCHEN_ORDER,
    LEVEL_SETS,
    MACHINE_FILE,
    NOOP,
    ROOT,
    UNTRAINED,
    Mode,
)
from apps.reproduce.overcooked.plan import generalist_run
from apps.reproduce.pipeline import play_seconds, results_file
from cec.agents.zoo import HUMAN_PROXY

if TYPE_CHECKING:
    from apps.zoo_build import PlannedRun
    from cec.agents.policy import Policy
    from cec.agents.zoo import ZooEntry
    from cec.evaluation.crossplay import EvalConfig
    from cec.evaluation.results import EpisodeTable
    from cec.training.config import TrainConfig


def level_spec(mode: Mode, level_set: str) -> str:
    if level_set == "classic":
        return ",".join(mode.kitchens)
    return pipeline.generated_levels(mode.generated_levels)


def human_proxies(mode: Mode) -> list[Policy]:
    """The `human_proxy` policies of `mode.proxies` (none when it is ''), numbered 0, 1, ... as their seeds:
    result tables tell policies apart by algorithm and seed, and `cec humans bc` gives its `bc_` and `hp_`
    proxies of a kitchen the same training seed."""
    if not mode.proxies:
        return []
    proxies = [
        p for p in pipeline.load_zoo_policies(mode.proxies, mode.proxies) if p.algorithm == HUMAN_PROXY
    ]
    return [dataclasses.replace(p, seed=i) for i, p in enumerate(proxies)]


def eval_config(mode: Mode, level_set: str, seed: int = 0, steps: int = EVAL_STEPS) -> EvalConfig:
    """How every policy plays on a level set: the mode's episodes per pair, seat order and kitchen, episodes
    of `steps` steps (the paper's 400, or the authors' code's 100: `AUTHORS_STEPS`), common random numbers
    from `seed` (per level and episode: the same games whatever the games per call, 8 on a CPU and 64 on an
    accelerator, which plays them side by side)."""
    import jax

    from cec.evaluation.crossplay import EvalConfig

    return EvalConfig(
        levels=level_spec(mode, level_set), episodes=mode.episodes[level_set], seed=seed,
        max_steps=steps, games_per_call=8 if jax.default_backend() == "cpu" else 64,
    )  # fmt: skip


def _eval_key(mode: Mode, steps: int = EVAL_STEPS) -> dict[str, object]:
    """What a table of `part_jobs` or `evaluate_controls` depends on besides its policies."""
    settings = {"episodes": mode.episodes, "kitchens": mode.kitchens, "levels": mode.generated_levels}
    return {**settings, "steps": steps}


@dataclasses.dataclass(frozen=True)
class Lineup:
    """One part of the cross-play on a level set: `players` (zoo entries, policies or stand-ins: anything
    with a name, seed and levels) on the kitchens of the level spec `levels`, the games that involve
    `involving` (None: all of them). It is played and cached on its own (`part_jobs`), under a key of its
    own players: it is played as soon as they are trained, and kept while they are unchanged, whatever
    else the zoo holds (another kitchen's agents, a run trained later)."""

    name: str
    level_set: str
    levels: str
    players: tuple
    involving: frozenset[str] | None = None

    @property
    def label(self) -> str:
        return f"{self.level_set} line-up {self.name}: "


def lineups(mode: Mode, players: Sequence, level_set: str) -> list[Lineup]:
    """Who meets whom on a level set, in line-ups that can be played as soon as their players are trained.
    On the classic kitchens, per kitchen, on that kitchen: the generator-trained agents with each other,
    then the kitchen's agents one algorithm at a time (`KITCHEN_ORDER`), each with the generator-trained
    agents and the kitchen's algorithms before it (only the games that involve the new algorithm). Each
    agent plays the kitchens it plays, and the common random numbers are drawn per kitchen and episode, so
    splitting the kitchens changes no game. On the held-out kitchens the same, every kitchen's agents free
    of their kitchen: the generator-trained agents with each other, then per training kitchen its
    algorithms one at a time. A seed of a single-kitchen algorithm is then, as on the classic kitchens,
    its agents of every kitchen: the result table names a policy by algorithm and seed, and a pair's score
    averages its kitchens."""
    generalists = tuple(p for p in players if p.levels is None)
    by_kitchen: dict[str, list] = {}
    for p in players:
        if p.levels is not None:
            by_kitchen.setdefault(",".join(p.levels), []).append(p)

    def nested(prefix: str, levels: str, own: Sequence) -> list[Lineup]:
        order = {a: i for i, a in enumerate(KITCHEN_ORDER)}
        algorithms = sorted(dict.fromkeys(p.algorithm for p in own), key=lambda a: order.get(a, len(order)))
        parts, before = [], generalists
        for algorithm in algorithms:
            agents = tuple(p for p in own if p.algorithm == algorithm)
            names = frozenset(p.name for p in agents)
            parts.append(Lineup(f"{prefix}{algorithm}", level_set, levels, (*before, *agents), names))
            before = (*before, *agents)
        return parts

    if level_set == "classic":
        parts = []
        for k in mode.kitchens:
            parts += [
                Lineup(f"{k}-generalists", level_set, k, generalists),
                *nested(f"{k}-", k, by_kitchen.get(k, [])),
            ]
        return parts
    spec = level_spec(mode, level_set)
    parts = [Lineup("generalists", level_set, spec, generalists)] if generalists else []
    for kitchen, own in by_kitchen.items():
        parts += nested(f"{kitchen}-", spec, [dataclasses.replace(p, levels=None) for p in own])
    return parts


def part_jobs(
    mode: Mode, entries: Sequence[ZooEntry], work: Path, *, log: TextIO, seed: int = 0,
    steps: int = EVAL_STEPS,
) -> list[pipeline.Job]:  # fmt: skip
    """Every line-up of `entries` (`lineups`) on both level sets with the scripted cook (and on the classic
    kitchens the human proxies of that kitchen), as cached tables in `<steps folder>/parts/<level
    set>-<line-up>` (`steps_folder`), each keyed by the settings and its own players and partners (name,
    seed, checkpoint state's SHA-256). Playing one loads only its players."""
    from cec.agents.zoo import load_zoo

    proxy_entries = load_zoo(mode.proxies) if mode.proxies else []
    jobs = []
    for level_set in LEVEL_SETS:
        for lineup in lineups(mode, entries, level_set):
            config = dataclasses.replace(eval_config(mode, level_set, seed, steps), levels=lineup.levels)
            partners = [] if level_set == "heldout" else [
                [e.name, e.sha256] for e in proxy_entries if e.levels is None or lineup.levels in e.levels
            ]  # fmt: skip
            key = {
                **_eval_key(mode, steps), "level_set": level_set, "lineup": lineup.name,
                "players": [[p.name, p.seed, p.sha256] for p in lineup.players], "proxies": partners,
                "involving": None if lineup.involving is None else sorted(lineup.involving),
            }  # fmt: skip
            play = functools.partial(_play_lineup, mode, lineup, config, log=log)
            jobs.append(pipeline.Job(steps_folder(work, steps) / PARTS / f"{level_set}-{lineup.name}",
                                     key, lineup.label, play))  # fmt: skip
    return jobs


def _play_lineup(mode: Mode, lineup: Lineup, config: EvalConfig, *, log: TextIO) -> EpisodeTable:
    """One line-up's cross-play with the cook (and on a classic kitchen its human proxies, both seat
    orders), logged with how many episodes it played and how long it took. Proxies that cannot play with
    the agents (another network) are the table's skipped entries, with the reason."""
    from cec.agents.policy import scripted_policy
    from cec.evaluation.crossplay import crossplay, eval_levels, plan_games

    t0 = time.perf_counter()
    players = pipeline.load_entry_policies(lineup.players, f"{lineup.label}zoo")
    cook = scripted_policy(COOK, COOK, env=players[0].env, algorithm=COOK)
    partners = [cook]
    if lineup.level_set == "classic":
        partners += [p for p in human_proxies(mode) if p.levels is None or lineup.levels in p.levels]
    levels = eval_levels("overcooked", config.levels)
    games = plan_games([*players, *partners], levels.names, config.pairs, lineup.involving)
    planned = sum(len(g.levels) for g in games) * config.episodes
    done, said = 0, t0

    def progress(call: str) -> None:  # crossplay's line per call: "<n> game(s) x <m> episode(s) ..."
        nonlocal done, said
        counts = re.match(r"(\d+) game\(s\) x (\d+) episode", call)
        done += int(counts[1]) * int(counts[2]) if counts else 0
        if time.perf_counter() - said >= PROGRESS_S:
            said, share = time.perf_counter(), f"{done:,} of {planned:,} episodes ({done / planned:.0%})"
            pipeline.note(log, f"{lineup.label}{share}, {done / max(said - t0, 1e-9):.0f} episodes/s")

    table = crossplay([*players, *partners], levels, config, involving=lineup.involving, progress=progress)
    n = len(partners) - 1
    with_whom = "the cook" + (f" and {n} human prox{'y' if n == 1 else 'ies'}" if n else "")
    where = f"{len(players)} agents + {with_whom} on {len(levels.names)} {lineup.level_set} kitchens"
    pipeline.note(log, f"{lineup.label}{where}: {len(table)} episodes in {time.perf_counter() - t0:.0f}s")
    return table


def ready_jobs(
    mode: Mode, plan: Sequence[PlannedRun], zoo_dir: Path, work: Path, *, log: TextIO
) -> tuple[list[pipeline.Job], int]:  # fmt: skip
    """The line-ups (`part_jobs`, at both episode lengths) whose players are all trained, and how many
    line-ups the whole zoo plays."""
    from apps.zoo_build import manifest_entries
    from cec.agents.zoo import ZooEntry, parse_zoo

    planned = [
        ZooEntry(name, "", r.algorithm, seed, r.levels)
        for r in plan for seed, name in zip(r.seeds, r.policy_names, strict=True)
    ]  # fmt: skip
    whole = {
        (ls, part.name): {p.name for p in part.players}
        for ls in LEVEL_SETS for part in lineups(mode, planned, ls)
    }  # fmt: skip
    lengths = (EVAL_STEPS, AUTHORS_STEPS)
    finished = [r for r in plan if r.finished]
    if not finished:
        return [], len(whole) * len(lengths)
    entries = parse_zoo({"policies": manifest_entries(finished, zoo_dir)}, zoo_dir, where=str(zoo_dir))
    ready = {
        (ls, part.name) for ls in LEVEL_SETS for part in lineups(mode, entries, ls)
        if whole.get((ls, part.name)) == {p.name for p in part.players}
    }  # fmt: skip
    jobs = [
        j for steps in lengths for j in part_jobs(mode, entries, work, log=log, steps=steps)
        if (j.key["level_set"], j.key["lineup"]) in ready
    ]  # fmt: skip
    return jobs, len(whole) * len(lengths)


def play_ready(mode: Mode, plan: Sequence[PlannedRun], zoo_dir: Path, work: Path, *, log: TextIO) -> int:
    """Between training runs (`Zoo.build`'s `between`): plays every line-up whose players are all trained
    (`ready_jobs`) that no other invocation is playing, before the rest of the zoo is trained; the number
    played. So a kitchen's games are in the work folder once its agents are: its checkpoints are no longer
    needed for the report (a reproduction carried from machine to machine keeps its runs' records, not
    their parameters: `scripts/carry_run.py`)."""
    return pipeline.play_unclaimed(ready_jobs(mode, plan, zoo_dir, work, log=log)[0], log=log)


def played_lineups(mode: Mode, work: Path) -> tuple[int, int]:
    """For `--plan`: how many line-ups are played (in the work folder under their players' present
    checkpoints), of how many the zoo plays."""
    from apps.reproduce.overcooked.plan import zoo

    the_zoo = zoo(mode, work)
    jobs, total = ready_jobs(mode, the_zoo.plan(), the_zoo.zoo_dir, work, log=io.StringIO())
    found = [j for j in jobs if pipeline.stored_key(j.folder, j.key)]
    return len(found), total


def cec_config(mode: Mode, work: Path) -> TrainConfig:
    """The config of the work folder's CEC agents: their run's recorded `config.yaml` (a folder trained by
    an earlier version of the mode has that version's network), else the mode's preset."""
    from cec.config import load_config
    from cec.training.config import TrainConfig

    recorded = generalist_run(mode, work, "cec") / "config.yaml"
    if recorded.is_file():
        return load_config(TrainConfig, recorded)
    return load_config(TrainConfig, str(ROOT / mode.preset), list(mode.overrides))


def control_policies(mode: Mode, cfg: TrainConfig) -> list[Policy]:
    """The controls beside every score with the cook (and a chance level for XP and SP): the CEC network
    of `cfg` (`cec_config`) at its random initialisation, one per CEC seed (`untrained`), and the agent
    that always stays (`noop`): what the cook delivers with a partner that learned nothing, so that an
    agent's own contribution reads as the difference."""
    import jax

    from cec.agents.policy import random_policy, scripted_policy

    untrained = [
        random_policy(f"{UNTRAINED}-s{s}", jax.random.PRNGKey(s), env=cfg.env, network=cfg.network_config,
                      algorithm=UNTRAINED, seed=s)
        for s in mode.seeds["cec"]
    ]  # fmt: skip
    return [*untrained, scripted_policy(NOOP, NOOP, env=cfg.env, algorithm=NOOP)]


def evaluate_controls(mode: Mode, cfg: TrainConfig, *, log: TextIO, seed: int = 0) -> EpisodeTable:
    """The controls (`control_policies` of `cfg`) with each other and the cook on both level sets, as
    `part_jobs` plays the algorithms (the cook's own games left out: the line-ups have them)."""
    from cec.agents.policy import scripted_policy
    from cec.evaluation.crossplay import crossplay, eval_levels
    from cec.evaluation.results import EpisodeTable

    controls = control_policies(mode, cfg)
    cook = scripted_policy(COOK, COOK, env=controls[0].env, algorithm=COOK)
    tables = []
    for level_set in LEVEL_SETS:
        config = eval_config(mode, level_set, seed)
        t0 = time.perf_counter()
        levels = eval_levels("overcooked", config.levels)
        table = crossplay([*controls, cook], levels, config, involving={c.name for c in controls})
        tables.append(table)
        pipeline.note(log, f"controls on the {level_set} kitchens: {len(table)} episodes in "
                      f"{time.perf_counter() - t0:.0f}s")  # fmt: skip
    return EpisodeTable.concat(tables)


def cached_controls(mode: Mode, work: Path, *, log: TextIO, commit: str) -> EpisodeTable:
    """`evaluate_controls`, or the table an earlier invocation wrote in `work/controls` while the settings
    are unchanged (the untrained network: that of the folder's CEC agents, `cec_config`). They need no
    trained agent, so `--report-only` plays them when a work folder lacks them. `commit`: the checkout's
    as the command started (written beside a table it plays, with the machine)."""
    from apps.reproduce.pipeline import cached_table

    cfg = cec_config(mode, work)
    network = dataclasses.asdict(cfg.network_config)
    key = {**_eval_key(mode), "network": network, "seeds": mode.seeds["cec"]}
    folder = work / "controls"
    folder.mkdir(parents=True, exist_ok=True)

    # they may be played by another machine than the zoo: it is named in the report
    def play() -> EpisodeTable:
        table = evaluate_controls(mode, cfg, log=log)
        ran_on = {"machine": machine_info(), "commit": commit}
        (folder / MACHINE_FILE).write_text(json.dumps(ran_on, indent=1) + "\n")
        return table

    return cached_table(folder, key, play, label="controls: ", log=log)


def cached_evaluation(
    mode: Mode, manifest: Path, work: Path, *, log: TextIO, commit: str, steps: int = EVAL_STEPS
) -> EpisodeTable:
    """Every line-up's table (`part_jobs`: every pair, XP, SP, ad hoc, with the cook, on the classic
    kitchens with the human proxies, both seat orders) as one table, or the table an earlier invocation
    wrote when neither the zoo (checkpoints pinned by SHA-256) nor the settings changed
    (`apps.reproduce.pipeline.cached_table`). A line-up an earlier invocation played with the same players
    is read, not played (the CPU version's take minutes each on the 2-vCPU Xeon); invocations side by side
    (two builders of one work folder) share the line-ups out (`pipeline.shared_tables`). The invocation
    that assembles it writes `machine.json` beside it: this machine, `commit` and the commits that wrote
    the agents' checkpoints (a zoo trained over several invocations). `steps`: the episodes' length; the
    table of another length than `EVAL_STEPS` (the authors' 100, `AUTHORS_STEPS`) lives in
    `work/steps<steps>` (`steps_folder`), the same games cut short."""
    folder = steps_folder(work, steps)
    folder.mkdir(parents=True, exist_ok=True)
    from cec.agents.zoo import load_zoo
    from cec.checkpoints import read_meta
    from cec.evaluation.results import EpisodeTable

    entries = load_zoo(manifest)
    proxies = sorted([e.name, e.sha256] for e in load_zoo(mode.proxies)) if mode.proxies else []
    zoo = sorted([e.name, e.seed, e.sha256] for e in entries)
    # `pairs`: what a table played with other line-ups lacks (or holds twice); such a table is assembled again
    key = {**_eval_key(mode, steps), "zoo": zoo, "proxies": proxies, "pairs": "line-ups by kitchen"}
    label = "" if steps == EVAL_STEPS else f"{steps}-step episodes: "
    if (found := pipeline.stored_table(folder, key, label=label, log=log)) is not None:
        return found
    jobs = part_jobs(mode, entries, work, log=log, steps=steps)
    played = EpisodeTable.concat(pipeline.shared_tables(jobs, log=log))

    def assemble() -> EpisodeTable:  # the line-ups' table, with their times and machine
        # the line-ups' own times, also those an earlier or interrupted invocation played
        seconds = sum(play_seconds(job.folder) for job in jobs)
        (folder / pipeline.PLAY_TIME_FILE).write_text(json.dumps({"seconds": seconds}) + "\n")
        trained = {
            _short(read_meta(e.checkpoint)["metadata"].get("code_version", "unknown")) for e in entries
        }
        ran_on = {"machine": machine_info(), "commit": commit, "trained_at": sorted(trained)}
        (folder / MACHINE_FILE).write_text(json.dumps(ran_on, indent=1) + "\n")
        return played

    return pipeline.cached_table(folder, key, assemble, label=label, log=log)


def steps_folder(work: Path, steps: int) -> Path:
    """Where the cross-play table of `steps`-step episodes lives: `work` itself for `EVAL_STEPS`, else
    `work/steps<steps>`."""
    return work if steps == EVAL_STEPS else work / f"steps{steps}"


def cached_short(work: Path) -> EpisodeTable | None:
    """For `--report-only`: the 100-step table (`AUTHORS_STEPS`) a complete invocation left in the work
    folder, None where there is none (a folder played before the reproduction played it, whose checkpoints
    are not kept)."""
    from cec.evaluation.results import read_csv

    folder = steps_folder(work, AUTHORS_STEPS)
    done = results_file(folder).is_file() and (folder / "results.key.json").is_file()
    return read_csv(results_file(folder)) if done else None


def _short(version: str) -> str:
    """A commit as `code_version()` records it (40 hex digits, `+dirty` for a changed tree), abbreviated."""
    sha, dirty, rest = version.partition("+")
    return sha[:7] + dirty + rest


PROGRESS_S = 120.0  # how often a line-up being played logs how far it is

PARTS = "parts"  # in the work folder (and `steps100/`): each line-up's games (`part_jobs`)

CURVES = "curves"  # in the work folder: the milestone checkpoints' games (`cached_curves`)


def cached_curves(mode: Mode, work: Path, *, log: TextIO, report_only: bool = False) -> EpisodeTable | None:
    """Cross-play learning curves of the generator-trained runs: at each checkpoint a run saved (its
    milestones and its last), its seeds with each other on the held-out kitchens (`cec.evaluation.
    milestones`), as the evaluation plays them; cached in `work/curves` while neither the checkpoints nor
    the settings changed. `report_only`: the cached games whatever their key (a folder without its
    checkpoints), None where there are none."""
    from apps.reproduce.pipeline import cached_table
    from cec.checkpoints import read_meta
    from cec.evaluation.crossplay import eval_levels
    from cec.evaluation.milestones import checkpoints_by_update, play_milestone
    from cec.evaluation.results import EpisodeTable, read_csv

    folder = work / CURVES
    if report_only:
        cached = results_file(folder)
        return read_csv(cached) if cached.is_file() else None
    runs = {a: generalist_run(mode, work, a) for a in GENERALISTS}
    saved = {a: checkpoints_by_update([run]) for a, run in runs.items() if run.is_dir()}
    config = eval_config(mode, "heldout")
    states = {a: [read_meta(p)["sha256"] for ps in s.values() for p in ps] for a, s in saved.items()}
    key = {**_eval_key(mode), "checkpoints": states}  # each checkpoint's state by its SHA-256
    folder.mkdir(parents=True, exist_ok=True)

    def play() -> EpisodeTable:
        levels = eval_levels("overcooked", config.levels)
        return EpisodeTable.concat(
            [play_milestone(a, paths, levels, config) for a, s in saved.items() for paths in s.values()]
        )

    return cached_table(folder, key, play, label="learning curves: ", log=log)


def planned_episodes(mode: Mode) -> dict[str, int]:
    """The episodes the evaluation plays, by part: `part_jobs`' on each level set (every line-up with the
    cook, the human proxies on the classic kitchens), the controls' (`evaluate_controls`) and the learning
    curves' (`cached_curves`: every seed pair of each CEC and CEC-E3T checkpoint the preset saves), counted
    as they are played, from the mode alone (nothing loaded)."""
    from cec.agents.policy import Policy
    from cec.agents.zoo import load_zoo
    from cec.config import load_config
    from cec.evaluation.crossplay import plan_games
    from cec.training.config import TrainConfig

    def stand_in(name: str, algorithm: str, levels: tuple[str, ...] | None = None) -> Policy:
        return Policy(name, algorithm, 0, None, None, None, levels)  # type: ignore[arg-type]

    def episodes(lineup: Sequence[Policy], levels: str, involving: frozenset[str] | None = None) -> int:
        names = levels.split(",")
        set_of = "classic" if names[0] in mode.kitchens else "heldout"
        games = plan_games(lineup, names, "all", involving)
        return sum(len(g.levels) for g in games) * mode.episodes[set_of]

    agents = [
        stand_in(f"{algo}-{kitchen}-s{s}", algo, (kitchen,) if kitchen else None)
        for algo in ALGORITHMS
        for kitchen in (("",) if algo in GENERALISTS else mode.kitchens)
        for s in mode.seeds[algo]
    ]
    cook = stand_in(COOK, COOK)
    proxies = [
        stand_in(e.name, HUMAN_PROXY, e.levels) for e in (load_zoo(mode.proxies) if mode.proxies else [])
        if e.algorithm == HUMAN_PROXY
    ]  # fmt: skip
    controls = [*(stand_in(f"{UNTRAINED}-s{s}", UNTRAINED) for s in mode.seeds["cec"]), stand_in(NOOP, NOOP)]
    partners = {"classic": [cook, *proxies], "heldout": [cook]}

    def with_partners(lineup: Lineup) -> list[Policy]:
        own = [p for p in partners[lineup.level_set] if p.levels is None or lineup.levels in p.levels]
        return [*lineup.players, *own]

    counts = {
        level_set: sum(episodes(with_partners(part), part.levels, part.involving)
                       for part in lineups(mode, agents, level_set))
        for level_set in LEVEL_SETS
    }  # fmt: skip
    names = frozenset(c.name for c in controls)
    counts["controls"] = sum(
        episodes([*controls, cook], level_spec(mode, level_set), names) for level_set in LEVEL_SETS
    )
    milestones = set(load_config(TrainConfig, str(ROOT / mode.preset)).checkpoint.milestones) | {1.0}
    counts["curves"] = sum(
        len(milestones)
        * episodes([stand_in(f"{a}-s{s}", a) for s in mode.seeds[a]], level_spec(mode, "heldout"))
        for a in GENERALISTS
    )
    return counts
