"""Cross-play evaluation: the partner zoo, cross-play as a library, the result table, statistics, game
theory and reports (docs/evaluation.md).

    from cec.evaluation import EvalConfig, crossplay, eval_levels, load_policies, load_zoo, write_csv

    policies, skipped = load_policies(load_zoo("zoo.yaml"))
    table = crossplay(policies, eval_levels("overcooked", "heldout"), EvalConfig(episodes=4), skipped=skipped)
    write_csv(table, "results.csv")           # then: cec report results.csv --out report/

Plotting (`cec.evaluation.report`) imports matplotlib on use; alpha-rank needs the `egta` extra.
"""

from cec.agents.policy import Policy, load_policies, load_policy, random_policy
from cec.agents.zoo import ZooEntry, load_zoo, parse_zoo
from cec.evaluation.crossplay import (
    EvalConfig,
    EvalLevels,
    Game,
    crossplay,
    episode_key,
    eval_levels,
    plan_games,
)
from cec.evaluation.results import EpisodeTable, ResultsError, SkippedEntry, read_csv, write_csv

__all__ = [
    "EpisodeTable",
    "EvalConfig",
    "EvalLevels",
    "Game",
    "Policy",
    "ResultsError",
    "SkippedEntry",
    "ZooEntry",
    "crossplay",
    "episode_key",
    "eval_levels",
    "load_policies",
    "load_policy",
    "load_zoo",
    "parse_zoo",
    "plan_games",
    "random_policy",
    "read_csv",
    "write_csv",
]
