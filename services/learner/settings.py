"""Where each training setting acts when the distributed learner trains a run (`cec up`, `cec train
--distributed`, with Ray or `distributed.pool=local`): every field of `TrainConfig`, by its dotted path,
is either honoured (and this says what reads it) or refused by name before anything starts.

The learner and every actor build the same `Trainer` from the run's whole `TrainConfig` (the actors with
`devices=1`): the rollout (`Trainer.collect`), the update (`Trainer.learn`), the initial state
(`Trainer.init`) and the checkpoints and metrics (`RunFiles`, `run_updates`) are `cec train`'s own, so a
setting they read acts in both topologies; kitchens that stream from the level server carry the whole
generator config across the wire (`cec.levels.wire`). `tests/services/test_settings_walk.py` fails for a
`TrainConfig` field placed nowhere here, and checks each refusal through `cec up` in both pools.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Iterator

from cec.training.config import TrainConfig

#: Honoured settings (a dotted path, or a prefix ending in `.*` for a whole group) and what reads them.
HONOURED: dict[str, str] = {
    "algorithm": "checked against the partner kind and levels; recorded in checkpoints and events",
    "seed": "the seeds' initial keys (Trainer.init); the level server's and the streams' seeds",
    "num_seeds": "the seeds trained together, vmapped in the actors' rollouts and the learner's update",
    "num_envs": "split evenly over the actors (refused when it does not split)",
    "num_steps": "each actor's rollout length",
    "total_env_steps": "the run's updates (run_updates) and the annealed schedules",
    "updates_per_call": "cec train fuses this many updates in one compiled call; the learner updates once "
    "per gathered batch: the same updates",
    "devices": "the learner's data-parallel update (each actor plays on one device); refused with several "
    "seeds",
    "network": "the network of the learner's and the actors' Trainer",
    "network_overrides": "the network of the learner's and the actors' Trainer",
    "env.name": "the game the actors play and the learner observes (expand)",
    "env.levels": "the actors' levels: streamed from the level server (generator) or drawn from the keys",
    "env.overcooked.*": "the game's rewards and resets: the actors' rollouts and the learner's observations",
    "env.dual_destination.*": "the game's settings: the actors' rollouts and the learner's observations",
    "env.generator.*": "carried whole to the level server in every stream request (cec.levels.wire), or read "
    "by the actors' local draws",
    "ppo.*": "the learner's update (Trainer.learn) and its optimiser",
    "checkpoint.*": "the learner's checkpoints (RunFiles, run_updates)",
    "partner.*": "the actors' partner in the rollout (Trainer.collect; FCP's population loaded by each "
    "actor) and the learner's loss masks",
    "init_from": "the learner's initial parameters (Trainer.init)",
    "init_from_seed": "the learner's initial parameters (Trainer.init)",
    "tracking.*": "the learner's TensorBoard events and W&B mirror (RunFiles)",
    "run_dir": "where the learner writes the run",
    "name": "the run's name (its folder, its events, its checkpoints' ids)",
}
#: Settings the distributed learner refuses at start, by name, and when.
REFUSED: dict[str, str] = {
    "level_repeats": "any value but 1 (cec train only)",
    "env.generator.exclude_heldout": "false with kitchens streamed from a level server (it never streams the "
    "evaluation sets)",
}


def setting_paths(cls: type = TrainConfig, prefix: str = "") -> Iterator[str]:
    """Every leaf setting of a config dataclass by dotted path (an optional nested config counts as one)."""
    hints = typing.get_type_hints(cls)
    for field in dataclasses.fields(cls):
        kind = hints[field.name]
        if dataclasses.is_dataclass(kind):
            yield from setting_paths(kind, f"{prefix}{field.name}.")  # type: ignore[arg-type]
        else:
            yield f"{prefix}{field.name}"


def placed(path: str) -> str | None:
    """Where `path` acts (`HONOURED`) or when it is refused (`REFUSED`); None if it is placed nowhere."""
    for table in (REFUSED, HONOURED):
        if path in table:
            return table[path]
        group = next((k for k in table if k.endswith(".*") and path.startswith(k[:-1])), None)
        if group is not None:
            return table[group]
    return None
