"""The report's figures (this paper's own part): learning curves, cross-play learning curves, a GIF of a
median cross-play episode of two CEC seeds in a held-out kitchen, and `cec report` of the agents' games.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

import numpy as np

from apps.reproduce import pipeline
from apps.reproduce.overcooked.modes import EVAL_STEPS, GENERALISTS, Mode
from apps.reproduce.overcooked.sections import agent_games
from apps.reproduce.pipeline import results_file
from cec.evaluation.curves import metrics_file

if TYPE_CHECKING:
    from cec.evaluation.milestones import MilestonePoint
    from cec.evaluation.results import EpisodeTable


def write_figures(
    mode: Mode,
    work: Path,
    out: Path,
    table: EpisodeTable,
    points: Sequence[MilestonePoint],
    *,
    log: TextIO,
    policies: Path,
) -> dict[str, str]:
    """Learning curves of every run (PNG), the cross-play learning curves (`curve_points`), a GIF of a
    median cross-play episode (`crossplay_gif`) and `cec report` of the agents' games (`out/crossplay/`:
    heatmaps, seed matrices, the meta-game)."""
    from cec.evaluation.curves import plot_learning_curves
    from cec.evaluation.milestones import plot_milestones
    from cec.evaluation.report import write_report as crossplay_report

    figures = {}
    runs = {d.name: d for d in sorted((work / "zoo" / "runs").glob("*")) if metrics_file(d).exists()}
    generalist = tuple(f"{a}-" for a in GENERALISTS)
    cec_runs = {k: v for k, v in runs.items() if k.startswith(generalist)}
    if cec_runs:
        plot_learning_curves(cec_runs, out / "curves_cec.png", title="trained on the generator's kitchens")
        figures["CEC (and CEC-E3T) learning curves"] = "curves_cec.png"
    others = {k: v for k, v in runs.items() if not k.startswith(generalist)}
    if others:
        plot_learning_curves(others, out / "curves_baselines.png", title="single-kitchen runs")
        figures["Single-kitchen learning curves"] = "curves_baselines.png"
    if points:
        title = f"cross-play at each checkpoint, held-out kitchens ({EVAL_STEPS}-step episodes)"
        plot_milestones(points, out / "curves_xp.png", title=title)
        figures["Cross-play learning curves (held-out kitchens)"] = "curves_xp.png"
    figures.update(crossplay_gif(table, policies, out / "cec_xp_heldout.gif", log=log))
    crossplay_report(agent_games(table), out / "crossplay", sources=[str(results_file(work))])
    pipeline.note(log, f"figures: {', '.join(figures.values())}; crossplay/report.md")
    return figures


def crossplay_gif(
    table: EpisodeTable, policies: Path, gif: Path, *, log: TextIO | None = None
) -> dict[str, str]:
    """{caption: file name} of a GIF of the pair and held-out kitchen of the median-return cross-play
    episode of two different CEC seeds of `policies` (a zoo manifest) in `table`: a typical episode, not the
    best, replayed (another draw of the sampled actions); its caption says how it was chosen, the table's
    and the replay's return and the share of episodes that deliver nothing. Empty when there is none.

    Beside the GIF, `<gif>.json` records the episode it replays and the replay's return. Where `policies`
    cannot replay it (a work folder kept without its checkpoints), the GIF already in place is kept when
    that record names the episode `table` picks, and the caption comes from it; otherwise there is no GIF.
    """
    import jax

    from cec.agents.policy import load_policies
    from cec.agents.zoo import load_zoo
    from cec.envs.overcooked.render import rollout_frames, save_gif
    from cec.evaluation.crossplay import episode_states, eval_levels

    rows = table.select(
        (table.algorithm_a == "cec") & (table.algorithm_b == "cec") & (table.seed_a != table.seed_b)
        & np.char.startswith(table.level.astype(str), "generated_")
    )  # fmt: skip
    if not len(rows):
        return {}
    i = int(np.argsort(rows.returns, kind="stable")[len(rows) // 2])  # the median episode
    kitchen, seeds = str(rows.level[i]), [int(rows.seed_a[i]), int(rows.seed_b[i])]
    record = gif.with_suffix(".json")
    cec = (
        {p.seed: p for p in load_policies(load_zoo(policies))[0] if p.algorithm == "cec"}
        if policies.is_file()
        else {}
    )
    if all(seed in cec for seed in seeds):
        a, b = cec[seeds[0]], cec[seeds[1]]
        level = jax.tree.map(lambda x: x[0], eval_levels("overcooked", kitchen).levels)
        states, ret = episode_states(a, b, level, kitchen, max_steps=EVAL_STEPS)
        save_gif(rollout_frames(states, 24), gif, fps=10)
        replay = {"kitchen": kitchen, "seeds": seeds, "replay_return": float(ret)}
        record.write_text(json.dumps(replay, indent=1) + "\n")
    else:
        replay = json.loads(record.read_text()) if record.is_file() and gif.is_file() else {}
        if (replay.get("kitchen"), replay.get("seeds")) != (kitchen, seeds):
            if log is not None:
                pipeline.note(log, f"no GIF: {policies} cannot replay CEC seeds {seeds}; {gif} is not theirs")
            return {}
        if log is not None:
            pipeline.note(log, f"{gif.name} kept as it is: {policies} cannot replay it (no checkpoints)")
    zero = float(np.mean(rows.returns == 0))
    caption = (
        f"CEC seeds {seeds[0]} and {seeds[1]} (never trained together) in {kitchen}, a held-out kitchen: the "
        f"pair and kitchen of the median-return episode of {len(rows)} cross-play episodes (return "
        f"{rows.returns[i]:g}; {zero:.0%} of them deliver nothing), replayed: team return "
        f"{replay['replay_return']:g} per {EVAL_STEPS} steps"
    )
    return {caption: gif.name}
