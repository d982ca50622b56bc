"""The cross-play of `cec reproduce dual-destination`: per variant, every algorithm's seeds with each other
and with the scripted oracle partner on the fixed task and the held-out generated tasks, cached while the
zoo, the settings and the oracle's code are unchanged (`pipeline.cached_table`)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from apps.reproduce import pipeline
from apps.reproduce.dual_destination.modes import Mode
from apps.reproduce.dual_destination.paper import LEVEL_SET_TITLES, LEVEL_SETS, ORACLE, fixed_level_name

if TYPE_CHECKING:
    from cec.evaluation.results import EpisodeTable


def _generated_spec(mode: Mode) -> str:
    if mode.generated_levels >= 100:
        return "generated"
    return pipeline.generated_levels(mode.generated_levels)


def evaluate_variant(mode: Mode, variant: str, manifest: Path, *, log: TextIO, seed: int = 0) -> EpisodeTable:
    """Cross-play of the variant's zoo and the oracle partner -> one `EpisodeTable`.

    Per level set and algorithm, one evaluation of its seeds and the oracle partner, every pair: XP
    (two different seeds), SP, and every seed with the oracle (in both seats). Algorithms are evaluated
    apart (their networks may differ, and cross-algorithm pairs are not in the paper's figures); the
    oracle's self-play is kept once.
    """
    from cec.agents.policy import scripted_policy
    from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels
    from cec.evaluation.results import EpisodeTable

    policies = pipeline.load_zoo_policies(manifest, variant)
    oracle = scripted_policy("dd_oracle", ORACLE, algorithm=ORACLE)
    tables = []
    for level_set in LEVEL_SETS:
        spec = fixed_level_name(variant) if level_set == "fixed" else _generated_spec(mode)
        levels = eval_levels("dual_destination", spec)
        for greedy in (False, True):
            config = EvalConfig(
                levels=spec, episodes=mode.episodes[level_set], seed=seed, games_per_call=1, greedy=greedy
            )
            for k, algo in enumerate(mode.rows):
                group = [p for p in policies if p.algorithm == algo]
                t0 = time.perf_counter()
                # greedy: the seeds among themselves (XP, SP); sampled: with the oracle partner too
                table = crossplay(group if greedy else [*group, oracle], levels, config)
                if k and not greedy:  # the oracle's self-play once
                    table = table.select((table.policy_a != ORACLE) | (table.policy_b != ORACLE))
                tables.append(table)
                actions = "greedy" if greedy else "sampled"
                pipeline.note(
                    log,
                    f"{variant}: {len(group)} {algo} seeds{'' if greedy else ' + oracle partner'}, every "
                    f"pair, {actions} actions, on the {LEVEL_SET_TITLES[level_set]}: {len(table)} episodes "
                    f"in {time.perf_counter() - t0:.0f}s",
                )
    return EpisodeTable.concat(tables)


def evaluation_key(mode: Mode, variant: str, manifest: Path) -> dict[str, object]:
    """What a variant's results depend on: the evaluation settings, every zoo entry (its checkpoint and
    the state's SHA-256 that `cec zoo build` pinned) and the oracle partner's code."""
    entries = pipeline.zoo_entries(manifest)
    return {
        "variant": variant,
        "episodes": mode.episodes,
        "generated_levels": mode.generated_levels,
        "zoo": sorted(entries, key=str),
        "oracle_partner": oracle_partner_digest(),
    }


def oracle_partner_digest() -> str:
    """SHA-256 of the oracle partner's source (`cec.envs.dual_destination.partner`): what it played is not
    reused once it changes."""
    import hashlib

    from cec.envs.dual_destination import partner

    return hashlib.sha256(Path(partner.__file__).read_bytes()).hexdigest()


def cached_evaluation(mode: Mode, variant: str, manifest: Path, vdir: Path, *, log: TextIO) -> EpisodeTable:
    """`evaluate_variant`, or the table an earlier invocation wrote (`vdir/results.csv`) when nothing it
    depends on has changed (`evaluation_key`); see `apps.reproduce.pipeline.cached_table`."""
    from apps.reproduce.pipeline import cached_table

    key = evaluation_key(mode, variant, manifest)
    play = lambda: evaluate_variant(mode, variant, manifest, log=log)  # noqa: E731
    return cached_table(vdir, key, play, label=f"{variant}: ", log=log)
