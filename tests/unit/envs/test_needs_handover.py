"""`needs_handover` (Overcooked's `Game.needs_partner`, what keeps a scripted training partner to the kitchens
that need both seats) says of each state's kitchen what `cec.levels.kinds` says of the level."""

from __future__ import annotations

import jax

from cec.envs.overcooked.dynamics import needs_handover, reset
from cec.envs.overcooked.game import GAME
from cec.levels.heldout import heldout_levels
from cec.levels.kinds import Kind, kinds_of
from cec.levels.level import stack_levels


def test_it_agrees_with_the_kinds_on_every_validation_kitchen() -> None:
    levels = dict(heldout_levels())
    states = jax.vmap(lambda lv: reset(jax.random.PRNGKey(0), lv)[1])(stack_levels(list(levels.values())))
    got = jax.jit(jax.vmap(needs_handover))(states).tolist()
    want = [kind == Kind.HANDOVER for kind, _ in kinds_of(levels).values()]
    assert got == want
    assert 10 < sum(want) < len(want) - 10  # both answers occur (Forced Coordination among the first)
    assert GAME.needs_partner is needs_handover
    assert bool(needs_handover(jax.tree.map(lambda x: x[list(levels).index("forced_coord")], states)))
