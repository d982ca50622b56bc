"""Replay of recorded human-human steps through our dynamics: which reproduce the recorded next state.

Every recorded step is played by our `step` from the recorded state with the recorded joint action, and
its result compared with the recorded next state field by field (positions, facings, held items, counter
items, pots) and with the recorded reward (a delivery or not: the data pays 5 per soup, we pay 20). A
step that differs anywhere is a mismatch, listed under the fields that differ (`docs/humans.md` explains
each class that occurs).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from functools import cache

import jax
import numpy as np

from cec.envs.overcooked.dynamics import step
from cec.envs.overcooked.state import EnvParams, EnvState
from cec.humans.data import KITCHENS, Steps
from cec.levels.classic import classic_level

#: What is compared, in report order: `EnvState` fields and the delivery.
COMPARED = ("agent_pos", "agent_dir", "agent_inv", "items", "pot", "delivery")


@dataclass
class KitchenReplay:
    """One kitchen's replay: steps, exact ones, mismatches by the set of fields that differ, examples
    (row indices into the replayed `Steps`, up to `examples_per_class` per class)."""

    steps: int = 0
    exact: int = 0
    classes: Counter[str] = field(default_factory=Counter)
    examples: dict[str, list[int]] = field(default_factory=dict)

    @property
    def share(self) -> float:
        return self.exact / self.steps if self.steps else float("nan")


def replay_steps(steps: Steps, *, batch: int = 4096, examples_per_class: int = 3) -> dict[str, KitchenReplay]:
    """Replays every step, per kitchen (only kitchens with steps appear)."""
    out: dict[str, KitchenReplay] = {}
    for k, kitchen in enumerate(KITCHENS):
        rows = np.flatnonzero(steps.kitchen == k)
        if rows.size == 0:
            continue
        result = out[kitchen] = KitchenReplay()
        for start in range(0, rows.size, batch):
            idx = rows[start : start + batch]
            differs = mismatches(steps.select(idx), kitchen)
            for i, row in enumerate(idx):
                bad = [name for name, d in zip(COMPARED, differs[i], strict=True) if d]
                result.steps += 1
                if not bad:
                    result.exact += 1
                    continue
                label = "+".join(bad)
                result.classes[label] += 1
                seen = result.examples.setdefault(label, [])
                if len(seen) < examples_per_class:
                    seen.append(int(row))
    return out


def mismatches(steps: Steps, kitchen: str) -> np.ndarray:
    """bool[N, len(COMPARED)]: where our step from each recorded state differs from the recorded next."""
    ours = predicted_next(steps, kitchen)
    recorded = {
        "agent_pos": steps.next_agent_pos,
        "agent_dir": steps.next_agent_dir,
        "agent_inv": steps.next_agent_inv,
        "items": steps.next_items,
        "pot": steps.next_pot,
        "delivery": steps.reward > 0,
    }
    cols = []
    for name in COMPARED:
        a, b = np.asarray(ours[name]), np.asarray(recorded[name])
        cols.append((a.reshape(len(a), -1) != b.reshape(len(b), -1)).any(axis=1))
    return np.stack(cols, axis=1)


def predicted_next(steps: Steps, kitchen: str) -> dict[str, np.ndarray]:
    """Our next state (the compared fields) of every recorded step of `kitchen`."""
    out = _step_batch(kitchen)(steps.actions.astype(np.int32), *steps.state_fields())
    return jax.tree.map(np.asarray, out)


@cache
def _step_batch(kitchen: str):  # type: ignore[no-untyped-def]
    level = classic_level(kitchen)
    params = EnvParams(max_steps=2**30)  # the recorded games are longer than any episode of ours

    def one(actions, *state):  # type: ignore[no-untyped-def]
        nxt = step(jax.random.PRNGKey(0), EnvState(level, *state), actions, params)
        s = nxt.state
        return {
            "agent_pos": s.agent_pos,
            "agent_dir": s.agent_dir,
            "agent_inv": s.agent_inv,
            "items": s.items,
            "pot": s.pot,
            "delivery": nxt.reward > 0,
        }

    return jax.jit(jax.vmap(one))
