"""The Dual Destination oracle partner against a partner that adapts too: how often two best responders
that start from different plans chase each other instead of meeting (docs/dual_destination.md, "Known
limitation").

    python research/analyses/dd_oracle_chase.py       # 512 generated multi-task tasks, ~30 s on a CPU core
    python research/analyses/dd_oracle_chase.py --tasks 2048

Both seats play `oracle_partner_step`; seat 1 reads the pink goals as green (goal channels swapped), so its
joint plan starts from the other pair whenever both pairs are as quick. Printed per task set: the mean
normalised score (return / (2 x max_steps)) and the number of episodes that never reach a goal pair
(-0.5), beside the same seats without the swap (two identical oracles, which agree by construction).
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from cec.envs import dual_destination as dd
from cec.envs.dual_destination.partner import MEMORY_SIZE, oracle_partner_step

KEY = jax.random.PRNGKey(0)
PARAMS = dd.DDParams(multi_task=True)


def _episode(level: dd.DDLevel, swap: jax.Array) -> jax.Array:
    """The team return of one episode; `swap` is seat 1's channel order (identity: no swap)."""
    obs, state = dd.reset(KEY, level, PARAMS)

    def body(carry: tuple, _: None) -> tuple:
        obs, state, memory = carry
        memory, actions = jax.vmap(oracle_partner_step)(memory, obs.at[1].set(obs[1][..., swap]))
        out = dd.step(KEY, state, actions, PARAMS)
        return (out.obs, out.state, memory), out.reward

    carry = (obs, state, jnp.zeros((2, MEMORY_SIZE), jnp.float32))
    _, rewards = jax.lax.scan(body, carry, None, length=PARAMS.max_steps)
    return rewards.sum()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", type=int, default=512, help="generated multi-task tasks (default 512)")
    args = parser.parse_args()
    keys = jax.random.split(jax.random.PRNGKey(1), args.tasks)
    generated = jax.vmap(dd.generate_dd_level, in_axes=(0, None, None))(keys, True, dd.held_out_dd_levels())
    fixed = jax.tree.map(lambda x: x[None], dd.multi_task_level())
    play = jax.jit(jax.vmap(_episode, in_axes=(0, None)))
    scale = 2.0 * PARAMS.max_steps
    print(f"{'task set':28s} {'seat 1 reads':14s} {'mean score':>10s} {'never meet':>12s}")
    for name, levels in (("multi-task fixed task", fixed), (f"{args.tasks} generated multi-task", generated)):
        for label, order in (("as seat 0", [0, 1, 2, 3]), ("pink as green", [0, 1, 3, 2])):
            scores = np.asarray(play(levels, jnp.asarray(order))) / scale
            never = int(np.sum(scores <= -0.5 + 1e-9))
            print(f"{name:28s} {label:14s} {scores.mean():10.3f} {never:6d} of {len(scores)}")


if __name__ == "__main__":
    main()
