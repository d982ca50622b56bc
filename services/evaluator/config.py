"""Typed configuration of the evaluator service (YAML preset: configs/evaluator.yaml; `key=value` overrides).

    config = load_config(EvaluatorConfig, "configs/evaluator.yaml", ["store.url=redis://10.0.0.2:6379/0"])

Lists of records (`level_sets`, `groups`) are overridden whole, in YAML flow syntax:
`'level_sets=[{name: classic, levels: classic}]'`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from cec.config import ConfigError
from cec.evaluation.crossplay import EvalConfig
from services.ports import METRICS_PORTS
from services.store import StoreConfig

#: The partner group of self-play results (each seed of the checkpoint with itself).
SELF_PLAY = "self_play"
#: The partner group of cross-play within a checkpoint (each of its seeds with each of its other seeds).
CROSS_PLAY = "cross_play"
#: The result recorded for a checkpoint that could not be scored: (partner group, level set).
FAILED_GROUP = "failed"
FAILED_LEVEL_SET = "checkpoint"
GROUP_BY = ("algorithm", "partner", "zoo")
GAMES = ("overcooked", "dual_destination")
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.:@+-]{0,99}$")


def _check_label(value: str, what: str) -> None:
    if not _NAME.match(value):
        raise ConfigError(
            f"{what} {value!r} must be 1-100 characters from letters, digits and _ . : @ + -, not starting "
            "with . : @ + - (it names Redis results, result files and Prometheus label values)"
        )


@dataclass(frozen=True)
class LevelSetConfig:
    """A named set of levels every checkpoint of one game is scored on.

    Attributes:
        name: its label in results (`level_set` in Redis, the CSV's folder, Prometheus).
        env: the game it belongs to (`overcooked` or `dual_destination`); a checkpoint is scored on the
            level sets of its own game.
        levels: the levels, as `cec eval --levels` takes them (`cec.evaluation.crossplay.eval_levels`):
            Overcooked `classic`, `generated` (the 100 held-out generated kitchens), `heldout` (both),
            or comma-separated names; Dual Destination `fixed`, `multi_task`.
        max_levels: use only the first this many levels of the set, in its stable order (0: all). Caps
            the cost of large sets such as the 100 held-out kitchens (a fixed share, the same for every
            checkpoint, so that a run's scores compare).
        max_steps: episode length on this set (0: `play.max_steps`); the README's Overcooked protocol is
            400 steps whatever the training episode length.
    """

    name: str
    env: str = "overcooked"
    levels: str = "classic"
    max_levels: int = 0
    max_steps: int = 0

    def __post_init__(self) -> None:
        _check_label(self.name, "level set name")
        if self.env not in GAMES:
            raise ConfigError(f"level set {self.name!r}: env {self.env!r} is unknown; choose one of {GAMES}")
        if not self.levels.strip():
            raise ConfigError(f"level set {self.name!r}: levels is empty; e.g. classic or generated")
        if self.max_levels < 0:
            raise ConfigError(f"level set {self.name!r}: max_levels must be >= 0 (0: all levels)")
        if not 0 <= self.max_steps <= 100_000:
            raise ConfigError(
                f"level set {self.name!r}: max_steps must be in 0..100000 (0: play.max_steps), got "
                f"{self.max_steps}"
            )


@dataclass(frozen=True)
class PartnerGroupConfig:
    """An explicit partner group: these zoo entries are scored together under one label.

    Attributes:
        name: the group's label (`partner_group` in Redis and Prometheus).
        partners: zoo entry names in the group (entries in no explicit group are grouped by `group_by`).
    """

    name: str
    partners: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        _check_label(self.name, "partner group name")
        if self.name in (SELF_PLAY, CROSS_PLAY):
            raise ConfigError(f"partner group name {self.name!r} is reserved for the checkpoint's own seeds")
        if not self.partners:
            raise ConfigError(f"partner group {self.name!r} lists no partners")


#: The README's protocol: 400-step Overcooked episodes, both seats, on a fixed quarter of the validation
#: kitchens per checkpoint (the whole set would take a share of a 2-core machine that training needs; `cec
#: release` plays the whole set for the checkpoints it chooses among) and the five classic kitchens.
README_STEPS = 400


def _default_level_sets() -> tuple[LevelSetConfig, ...]:
    return (
        LevelSetConfig("validation", "overcooked", "generated", max_levels=25, max_steps=README_STEPS),
        LevelSetConfig("classic", "overcooked", "classic", max_steps=README_STEPS),
        LevelSetConfig("fixed", "dual_destination", "fixed"),
    )


#: The shipped zoo's partners a checkpoint meets by default: the CEC seeds (758M env steps, no teacher),
#: the kickstarted seeds (the scripted cook as a teacher) and the human proxies (each in its own kitchen).
DEFAULT_ZOO_ALGORITHMS = ("cec", "cec_teacher", "human_proxy")


@dataclass(frozen=True)
class EvaluatorConfig:
    """The evaluator service: where events come from, whom checkpoints play, where results go.

    Attributes:
        store: the Redis control plane (`store.url`, `store.key_prefix`, `store.claim_idle_s`, ...).
        zoo: zoo manifest (YAML/JSON, docs/evaluation.md); '' = none. Re-read before every checkpoint,
            so partners can be added while the service runs (a manifest that became unreadable is
            reported and the last good one kept).
        redis_zoo: also use the partners registered in Redis (`ControlPlane.add_partner`). A name that is
            also in the manifest is taken from the manifest. A Redis partner whose `env` is
            `overcooked:<classic kitchen>` plays on that kitchen only (a single-task agent).
        group_by: how zoo entries in no explicit group are grouped: `algorithm` (one group per algorithm
            label), `partner` (each entry its own group) or `zoo` (one group named `zoo`).
        groups: explicit partner groups (entry names); they take precedence over `group_by`.
        self_play: score each seed of the checkpoint with itself (partner group `self_play`).
        cross_play: score each seed of a checkpoint of several seeds with each of its other seeds (partner
            group `cross_play`; both seat orders): seeds of one run never trained together, so this is
            cross-play with partners never met, the README's headline protocol.
        zoo_algorithms: play only the zoo entries of these algorithm labels (e.g. `[cec, cec_teacher,
            human_proxy]` of the shipped zoo); empty: every entry.
        level_sets: the named level sets; a checkpoint plays those of its own game.
        play: how each game is played, as `cec eval` plays it (`cec.evaluation.crossplay.EvalConfig`):
            `episodes` per pairing, seat order and level; `max_steps` (0: the checkpoint's training
            episode length); `greedy` (argmax actions; the paper samples); `seed` of the common random
            numbers (the same for every checkpoint, so scores of checkpoints differ by the policies only);
            `games_per_call` (0: all games of a level set in one compiled call; 1 is fastest on a CPU).
            Its `levels` and `pairs` are the evaluator's own: each level set's, each seed with its partners.
        results_dir: result tables go to `<results_dir>/<run_id>/eval/update_<N>.csv` (with the runs'
            directory here, next to the run's checkpoints); '' = Redis only.
        consumer_group: Redis consumer group on the checkpoint stream; evaluators of one group share
            the work, each group scores every checkpoint.
        consumer_name: this evaluator's name in the group; keep it stable across restarts (a restart
            then resumes its own unfinished checkpoint at once).
        from_start: a new consumer group starts at the first checkpoint event ever published (else at
            events published after it was created).
        runs: score only checkpoints of these run ids (empty: all); others are acknowledged unscored.
        poll_s: longest wait for a new event before the loop checks for a stop request.
        metrics_port: Prometheus `/metrics` port on `metrics_host` (0: a free port, -1: off).
        metrics_host: bind address of the metrics endpoint.
    """

    store: StoreConfig = field(default_factory=StoreConfig)
    zoo: str = "shipped"
    redis_zoo: bool = True
    group_by: str = "algorithm"
    groups: tuple[PartnerGroupConfig, ...] = ()
    self_play: bool = True
    cross_play: bool = True
    zoo_algorithms: tuple[str, ...] = DEFAULT_ZOO_ALGORITHMS
    level_sets: tuple[LevelSetConfig, ...] = field(default_factory=_default_level_sets)
    play: EvalConfig = field(default_factory=lambda: EvalConfig(episodes=1, games_per_call=1))
    results_dir: str = "runs"
    consumer_group: str = "evaluator"
    consumer_name: str = "evaluator-0"
    from_start: bool = True
    runs: tuple[str, ...] = ()
    poll_s: float = 2.0
    metrics_port: int = METRICS_PORTS["evaluator"]
    metrics_host: str = "127.0.0.1"

    def __post_init__(self) -> None:
        if self.group_by not in GROUP_BY:
            raise ConfigError(f"group_by {self.group_by!r} is unknown; choose one of {list(GROUP_BY)}")
        if not self.level_sets:
            raise ConfigError(
                "level_sets is empty; name at least one, e.g. [{name: classic, levels: classic}]"
            )
        names = [s.name for s in self.level_sets]
        if len(set(names)) != len(names):
            raise ConfigError(f"level set names must be unique, got {names}")
        groups = [g.name for g in self.groups]
        if len(set(groups)) != len(groups):
            raise ConfigError(f"partner group names must be unique, got {groups}")
        listed = [p for g in self.groups for p in g.partners]
        twice = sorted({p for p in listed if listed.count(p) > 1})
        if twice:
            raise ConfigError(f"zoo entries {twice} are in more than one partner group; put each in one")
        if not (self.self_play or self.zoo or self.redis_zoo):
            raise ConfigError("nothing to score: set self_play, a zoo manifest or redis_zoo")
        if self.poll_s <= 0:
            raise ConfigError(f"poll_s must be > 0, got {self.poll_s}")
        if not -1 <= self.metrics_port <= 65535:
            raise ConfigError(
                f"metrics_port must be a TCP port in 0..65535 or -1 (off), got {self.metrics_port}"
            )
        for value, what in ((self.consumer_group, "consumer_group"), (self.consumer_name, "consumer_name")):
            if not value or any(c.isspace() or c == "|" for c in value):
                raise ConfigError(f"{what} {value!r} must be non-empty, without spaces or '|'")

    def level_sets_of(self, env: str) -> tuple[LevelSetConfig, ...]:
        """The level sets a checkpoint of game `env` is scored on."""
        return tuple(s for s in self.level_sets if s.env == env)
