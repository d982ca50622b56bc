"""Scripted policies: zoo entries without a checkpoint, played through the one rollout.

A scripted policy is a pure step function `(memory float32[M], obs) -> (memory, action)` of what one seat
observes. To batch it with networks in the same jitted cross-play call (`cec.evaluation.crossplay`),
`WithScripted` is an `ActorCritic` whose parameters carry a `scripted_kind` (0: the network, k > 0: the
k-th scripted kind); each seat's parameter set picks its own, so a network and a scripted policy can sit
in the two seats of one game. The scripted memory lives in the seat's slot of the rollout's recurrent
carry (zeroed at episode starts like an LSTM state), which is widened to hold it. Nothing in
`cec.training.rollout` knows about scripted policies.

    dd_oracle   Dual Destination's oracle partner (`cec.envs.dual_destination.partner`): best response to
                what the partner has shown, the oracle's joint plan before that
    cook        Overcooked's scripted cook (`cec.envs.overcooked.scripted.cook_step`): greedy shortest-path
                cooking from what its observation shows, yielding to its partner, 5% random actions
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from cec.agents.network import ActorCritic, LSTMState, init_params
from cec.config import ConfigError
from cec.envs.dual_destination import partner as dd_partner
from cec.envs.overcooked import scripted as oc_scripted
from cec.envs.overcooked import state as oc_state

#: The log-probability given to every action but the scripted one (a deterministic policy).
NEVER = -1e9


class ScriptedKind(NamedTuple):
    """A scripted policy kind.

    Attributes:
        env: the game it plays.
        memory_size: floats of memory it keeps per seat.
        step: (memory float32[memory_size], one seat's obs) -> (memory, action int32[]); pure, jittable.
        description: one line for listings and errors.
    """

    env: str
    memory_size: int
    step: Callable[[jax.Array, jax.Array], tuple[jax.Array, jax.Array]]
    description: str


SCRIPTED: dict[str, ScriptedKind] = {
    "dd_oracle": ScriptedKind(
        "dual_destination",
        dd_partner.MEMORY_SIZE,
        dd_partner.oracle_partner_step,
        "Dual Destination oracle partner: best response to the partner's observed choice",
    ),
    "cook": ScriptedKind(
        "overcooked",
        oc_scripted.COOK_MEMORY,
        oc_scripted.cook_step,
        "Overcooked scripted cook: greedy shortest-path cooking that yields to its partner",
    ),
    "noop": ScriptedKind(
        "overcooked",
        1,
        lambda memory, obs: (memory, jnp.int32(oc_state.Action.STAY)),
        "Overcooked control partner that always stays put (what the cook scores alone, in its way)",
    ),
}


def scripted_kind(kind: str) -> ScriptedKind:
    """The registered kind; `ConfigError` naming the known ones otherwise."""
    if kind not in SCRIPTED:
        raise ConfigError(f"unknown scripted policy {kind!r}; choose one of {sorted(SCRIPTED)}")
    return SCRIPTED[kind]


class WithScripted(ActorCritic):
    """`ActorCritic` plus scripted policies, chosen per parameter set by its `scripted_kind` leaf.

    Parameters: `{"params": {"net": <ActorCritic params>, "scripted_kind": int32[]}}`. The carry is
    `LSTMState(c, h)` with `carry_width` floats each: the network's LSTM state in the first
    `lstm_features`, a scripted policy's memory in `c[:memory_size]`. Outputs as `ActorCritic`; a
    scripted seat's logits are 0 for its action and `NEVER` for the others, its value 0.
    """

    scripted: tuple[str, ...] = ()

    @property
    def carry_width(self) -> int:
        memory = max((SCRIPTED[k].memory_size for k in self.scripted), default=0)
        return max(self.config.lstm_features, 1, memory)

    def initial_carry(self, batch_shape: tuple[int, ...]) -> LSTMState:
        zeros = jnp.zeros((*batch_shape, self.carry_width), jnp.float32)
        return LSTMState(zeros, zeros)

    @nn.compact
    def __call__(
        self, carry: LSTMState, obs: jax.Array, reset: jax.Array, history: jax.Array | None = None
    ) -> tuple[LSTMState, jax.Array, jax.Array]:
        kind = self.param("scripted_kind", lambda _: jnp.zeros((), jnp.int32))
        width = self.carry_width
        h = max(self.config.lstm_features, 1)
        net = ActorCritic(self.config, self.num_actions, name="net")
        (nc, nh), logits, value = net(LSTMState(carry.c[..., :h], carry.h[..., :h]), obs, reset, history)
        pad = [(0, 0)] * (nc.ndim - 1) + [(0, width - h)]
        out_c, out_h = jnp.pad(nc, pad), jnp.pad(nh, pad)
        for k, name in enumerate(self.scripted, start=1):
            s_c, s_logits = _run_scripted(SCRIPTED[name], carry.c, obs, reset, self.num_actions)
            use = kind == k
            out_c = jnp.where(use, s_c, out_c)
            out_h = jnp.where(use, jnp.zeros_like(out_h), out_h)
            logits = jnp.where(use, s_logits, logits)
            value = jnp.where(use, jnp.zeros_like(value), value)
        return LSTMState(out_c, out_h), logits, value


def _run_scripted(
    spec: ScriptedKind, c: jax.Array, obs: jax.Array, reset: jax.Array, num_actions: int
) -> tuple[jax.Array, jax.Array]:
    """Runs a scripted kind over [T, B] observations from memories `c` [B, W] (the first `memory_size`
    floats); returns (memories [B, W], logits [T, B, A])."""
    m = spec.memory_size

    def one_step(mem: jax.Array, xs: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        o, r = xs
        mem = jnp.where(r[:, None], 0.0, mem)
        mem, action = jax.vmap(spec.step)(mem, o)
        return mem, action

    mem, actions = jax.lax.scan(one_step, c[..., :m], (obs, reset))
    logits = jnp.where(jax.nn.one_hot(actions, num_actions) > 0, 0.0, NEVER).astype(jnp.float32)
    return jnp.concatenate([mem, c[..., m:]], axis=-1), logits


def with_scripted_params(params: Any, kind_index: int) -> dict:
    """`{"params": {"net": params["params"], "scripted_kind": kind_index}}` (0: the network itself)."""
    return {"params": {"net": params["params"], "scripted_kind": np.asarray(kind_index, np.int32)}}


def placeholder_params(network: ActorCritic, obs_shape: tuple[int, ...]) -> Any:
    """Zero parameters of `network`'s shapes (a scripted seat's unused network part)."""
    shapes = jax.eval_shape(lambda k: init_params(network, k, obs_shape), jax.random.PRNGKey(0))
    return jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), shapes)
