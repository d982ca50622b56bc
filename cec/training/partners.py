"""Partner strategies: who plays the other seat while the learner trains (one rollout, one update for all).

    self_play  both seats act with the learner's policy and both train (IPPO, CEC)
    fcp        Fictitious Co-Play: the other seat is a frozen partner drawn, per env and per episode, from a
               population of checkpoints (e.g. IPPO seeds at early / middle / final milestones); the
               learner's seat is drawn per env and episode too, and only the learner's seat trains
    e3t        E3T's mixture partner: the other seat acts with (1 - epsilon) * pi + epsilon * uniform (pi the
               learner's current policy); only the learner's own seat trains, so every trained action was
               drawn from pi and the PPO ratio needs no correction; the partner seat's stored log-prob is
               that of the mixture it acted with

Seats and partners are redrawn where an episode starts (the LSTM resets there anyway), independently per
env, from split keys; the partner's LSTM state lives in the partner seat's slot of the rollout carry.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cec.config import ConfigError

PARTNER_KINDS = ("self_play", "fcp", "e3t")
CHECKPOINT_PICKS = ("first", "middle", "last")


@dataclass(frozen=True)
class PopulationEntry:
    """Frozen partners from one training run.

    Attributes:
        run: the run directory (its milestone checkpoints are the candidates).
        seeds: which seeds of that run (empty: all of them).
        checkpoints: which milestone checkpoints, each `first`, `middle`, `last` (of the run's milestones
            in update order) or an update number.
    """

    run: str
    seeds: tuple[int, ...] = ()
    checkpoints: tuple[str, ...] = CHECKPOINT_PICKS


@dataclass(frozen=True)
class PartnerConfig:
    """The partner strategy of a training run (see the module docstring).

    Attributes:
        kind: `self_play`, `fcp` or `e3t`.
        population: FCP's population, as run directories x seeds x milestone checkpoints.
        epsilon: E3T's uniform-mixing weight of the partner seat (the paper's appendix: 0.5).
        predict_partner: history length K of the partner-modelling module added to the learner's network
            (E3T's: it predicts the partner's action from the core's features and the partner's last K
            actions, feeds the prediction to the actor, and trains on the partner's actual actions with
            `ppo.partner_coef`); 0: no module.
    """

    kind: str = "self_play"
    population: tuple[PopulationEntry, ...] = ()
    epsilon: float = 0.5
    predict_partner: int = 0

    def __post_init__(self) -> None:
        if self.kind not in PARTNER_KINDS:
            raise ConfigError(f"partner.kind {self.kind!r} is unknown; choose one of {list(PARTNER_KINDS)}")
        if (self.kind == "fcp") != bool(self.population):
            raise ConfigError(
                "partner.population lists FCP's frozen partners: give it with kind fcp, and only then"
            )
        if self.predict_partner < 0:
            raise ConfigError(f"partner.predict_partner must be >= 0, got {self.predict_partner}")
        if not 0.0 <= self.epsilon <= 1.0:
            raise ConfigError(f"partner.epsilon must lie in [0, 1], got {self.epsilon}")
        for entry in self.population:
            bad = [c for c in entry.checkpoints if c not in CHECKPOINT_PICKS and not c.isdigit()]
            if bad:
                raise ConfigError(
                    f"partner.population: checkpoints {bad} of {entry.run!r} are neither "
                    f"{'/'.join(CHECKPOINT_PICKS)} nor update numbers"
                )

    @property
    def learner_seat_only(self) -> bool:
        """Only the learner's own seat trains (the other seat's actions are not the learner's)."""
        return self.kind != "self_play"


SELF_PLAY = PartnerConfig()


class Population(NamedTuple):
    """FCP's frozen partners: `params` with a leading axis P, and a label per partner."""

    params: Any
    names: tuple[str, ...]


def mixture_log_probs(logits: jax.Array, epsilon: float) -> jax.Array:
    """log((1 - epsilon) * softmax(logits) + epsilon / A) over the last axis (E3T's partner policy)."""
    a = logits.shape[-1]
    if epsilon == 0.0:
        return jax.nn.log_softmax(logits)
    return jnp.logaddexp(jnp.log1p(-epsilon) + jax.nn.log_softmax(logits), jnp.log(epsilon / a))


def _pick(milestones: list[Any], pick: str) -> Any:
    if pick.isdigit():
        found = [c for c in milestones if c.update == int(pick)]
        return found[0] if found else None
    index = {"first": 0, "middle": len(milestones) // 2, "last": len(milestones) - 1}[pick]
    return milestones[index] if milestones else None


def load_population(config: PartnerConfig, env: Any, network: Any, obs_shape: tuple[int, ...]) -> Population:
    """Loads FCP's population and checks every partner fits the learner (same game, observation shape
    and network). Raises `ConfigError` listing every offending entry, before any training starts."""
    from cec import checkpoints
    from cec.evaluation.zoo import ZooEntry, load_policy
    from cec.training.tasks import Task

    params, names, problems = [], [], []
    for entry in config.population:
        milestones = [c for c in checkpoints.CheckpointStore(entry.run, keep_last=1).list() if c.milestone]
        if not milestones:
            problems.append(f"{entry.run}: no milestone checkpoints (is it a training run directory?)")
            continue
        for pick in entry.checkpoints:
            ckpt = _pick(milestones, pick)
            if ckpt is None:
                have = [c.update for c in milestones]
                problems.append(
                    f"{entry.run}: no milestone checkpoint {pick!r} (milestones at updates {have})"
                )
                continue
            seeds = entry.seeds or tuple(
                checkpoints.read_meta(ckpt.path).get("metadata", {}).get("seeds", ())
            )
            for seed in seeds:
                name = f"{Path(entry.run).name}/s{seed}/u{ckpt.update}"
                try:
                    policy = load_policy(ZooEntry(name=name, checkpoint=str(ckpt.path), seed=seed))
                except (checkpoints.CheckpointError, ConfigError, OSError, ValueError) as err:
                    problems.append(f"{name}: {err}")
                    continue
                why = []
                if policy.env.name != env.name:
                    why.append(f"plays {policy.env.name}, the learner {env.name}")
                elif Task.from_config(policy.env).obs_shape != obs_shape:
                    why.append(f"observes {Task.from_config(policy.env).obs_shape}, the learner {obs_shape}")
                if dataclasses.replace(policy.network, partner_history=0) != dataclasses.replace(
                    network, partner_history=0
                ):
                    why.append("has a different network (preset or widths) than the learner")
                if why:
                    problems.append(f"{name}: " + "; ".join(why))
                    continue
                params.append(policy.params)
                names.append(name)
    if problems or not params:
        raise ConfigError(
            "partner.population cannot be used:\n  - "
            + "\n  - ".join(problems or ["it resolves to no partner at all"])
            + "\nfix or drop those entries (each must be a milestone checkpoint of a run of the same game, "
            "observation shape and network)"
        )
    return Population(jax.tree.map(lambda *xs: jnp.asarray(np.stack(xs)), *params), tuple(names))
