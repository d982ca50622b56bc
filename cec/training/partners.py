"""Partner strategies: who plays the other seat while the learner trains (one rollout, one update for all).

    self_play  both seats act with the learner's policy and both train (IPPO, CEC)
    fcp        Fictitious Co-Play: the other seat is a frozen partner drawn, per env and per episode, from a
               population of checkpoints (e.g. IPPO seeds at early / middle / final milestones); the
               learner's seat is drawn per env and episode too, and only the learner's seat trains
    e3t        E3T's mixture partner: the other seat acts with (1 - epsilon) * pi + epsilon * uniform (pi the
               learner's current policy); only the learner's own seat trains, so every trained action was
               drawn from pi and the PPO ratio needs no correction; the partner seat's stored log-prob is
               that of the mixture it acted with
    scripted   a hand-written partner in a share of the episodes: where an episode starts, each env draws
               the game's scripted policy (`Game.scripted`: Overcooked's cook, from the full state) with
               probability `scripted_share` for the other seat, else the learner's own policy; only the
               learner's seat trains. `scripted_yields` false makes the cook never give way (it walks
               into the learner until the learner moves), so the learner meets someone it must go around;
               `scripted_both_seats` trains both seats of the episodes without the cook (as self-play does)
               and masks only the cook's seat, so self-play keeps its full data; `scripted_where_needed`
               draws the cook only where the level needs both seats (`Game.needs_partner`: Overcooked's
               kitchens that need a hand-over), so that no soup comes without the learner's half;
               `scripted_anneal_env_steps` lowers the share linearly to 0 over that many env steps, so that
               the learner meets the cook early and a copy of itself in the same kitchens later

Seats and partners are redrawn where an episode starts (the LSTM resets there anyway), independently per
env, from split keys; the partner's LSTM state lives in the partner seat's slot of the rollout carry.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from cec.config import ConfigError
from cec.training.schedules import anneal_to_zero

PARTNER_KINDS = ("self_play", "fcp", "e3t", "scripted")
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
        kind: `self_play`, `fcp`, `e3t` or `scripted`.
        population: FCP's population, as run directories x seeds x milestone checkpoints.
        epsilon: E3T's uniform-mixing weight of the partner seat (the paper's appendix: 0.5).
        predict_partner: history length K of the partner-modelling module added to the learner's network
            (E3T's: it predicts the partner's action from the core's features and the partner's last K
            actions, feeds the prediction to the actor, and trains on the partner's actual actions with
            `ppo.partner_coef`); 0: no module.
        scripted_share: the `scripted` kind's share of episodes whose partner is the scripted policy.
        scripted_epsilon: the scripted partner's share of uniformly random actions.
        scripted_yields: the scripted partner gives way where its route and the learner's collide.
        scripted_both_seats: the `scripted` kind trains both seats of the episodes the learner plays with
            itself, and only the learner's seat of those with the cook (the cook's seat weighs 0 in the
            loss); false: only the learner's seat trains in every episode.
        scripted_normalise_apart: the advantages of the steps with the scripted partner and of those
            without it are standardised apart (`cec.training.ppo.make_batch`), so the cook's episodes, whose
            returns spread several times wider, do not carry most of the policy gradient.
        scripted_where_needed: the scripted partner plays only episodes whose level neither seat can
            finish alone (`Game.needs_partner`; `scripted_share` of those), where it cannot score without
            the learner doing its half; the other episodes are self-play.
        scripted_anneal_env_steps: > 0: the scripted share falls linearly from `scripted_share` to 0 over
            this many env steps of training (`scripted_share_at`); 0: it stays at `scripted_share`.
    """

    kind: str = "self_play"
    population: tuple[PopulationEntry, ...] = ()
    epsilon: float = 0.5
    predict_partner: int = 0
    scripted_share: float = 0.5
    scripted_epsilon: float = 0.1
    scripted_yields: bool = True
    scripted_both_seats: bool = False
    scripted_normalise_apart: bool = False
    scripted_where_needed: bool = False
    scripted_anneal_env_steps: int = 0

    def __post_init__(self) -> None:
        if self.kind not in PARTNER_KINDS:
            raise ConfigError(f"partner.kind {self.kind!r} is unknown; choose one of {list(PARTNER_KINDS)}")
        if (self.kind == "fcp") != bool(self.population):
            raise ConfigError(
                "partner.population lists FCP's frozen partners: give it with kind fcp, and only then"
            )
        if self.predict_partner < 0:
            raise ConfigError(f"partner.predict_partner must be >= 0, got {self.predict_partner}")
        scripted_only = (
            "scripted_both_seats",
            "scripted_normalise_apart",
            "scripted_where_needed",
            "scripted_anneal_env_steps",
        )
        if self.kind != "scripted" and any(getattr(self, name) for name in scripted_only):
            raise ConfigError(
                f"partner.{', partner.'.join(scripted_only)} apply to kind scripted; "
                f"this partner is {self.kind!r}: drop them or set partner.kind: scripted"
            )
        if self.scripted_anneal_env_steps < 0:
            raise ConfigError(
                "partner.scripted_anneal_env_steps must be >= 0 (0: no anneal), "
                f"got {self.scripted_anneal_env_steps}"
            )
        for name in ("epsilon", "scripted_share", "scripted_epsilon"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"partner.{name} must lie in [0, 1], got {getattr(self, name)}")
        for entry in self.population:
            bad = [c for c in entry.checkpoints if c not in CHECKPOINT_PICKS and not c.isdigit()]
            if bad:
                raise ConfigError(
                    f"partner.population: checkpoints {bad} of {entry.run!r} are neither "
                    f"{'/'.join(CHECKPOINT_PICKS)} nor update numbers"
                )

    def scripted_share_at(self, env_steps: jax.Array) -> jax.Array:
        """The scripted partner's share of episodes after `env_steps` env steps of training (traced)."""
        return anneal_to_zero(self.scripted_share, env_steps, self.scripted_anneal_env_steps)

    @property
    def learner_seat_only(self) -> bool:
        """Only the learner's own seat trains (the other seat's actions are not the learner's)."""
        return self.kind != "self_play" and not self.masks_scripted_seat

    @property
    def masks_scripted_seat(self) -> bool:
        """Both seats are in the batch and the cook's seat of its episodes weighs 0 in the loss."""
        return self.kind == "scripted" and self.scripted_both_seats


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
