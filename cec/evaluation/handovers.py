"""Hand-overs in an episode: what each seat put where its partner could reach it, and what became of it.

Where neither seat can finish a soup alone (`cec.levels.kinds.Kind.HANDOVER`) a soup needs a hand-over:
an item put on a *shared counter* (a counter next to both seats' floor regions) and picked up by the
partner, or a pot that one seat fills and the other serves. Read from a played episode's states (`cec.
evaluation.crossplay.episode_states`), host-side:

    puts        items a seat put down on a shared counter
    taken       such items picked up by the partner (a hand-over across a counter)
    taken_back  such items picked up again by the seat that put them there
    pot_serves  soups served by a seat from a pot the partner put onions in (a hand-over through a pot)
    soups       soups delivered
    passes      the puts of an item the putting seat cannot use and its partner can (an onion or a plate
                by a seat whose region reaches no pot, a plated soup by one that reaches no goal): what the
                pass reward, `EnvParams.pass_reward`, pays
    passes_taken, passes_taken_back
                such items picked up by the partner, and by the seat that put them
    taken_back_soon
                items taken back within `SOON` steps of being put down: a seat that puts an item down and
                picks it up again at once, rather than coming back for it later

An episode that puts nothing on a shared counter never tried a hand-over; one whose items are never taken
has a partner that does not look at the counter; one whose items are taken and still delivers nothing
stalls after the hand-over.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, fields
from typing import Any

import jax.numpy as jnp
import numpy as np

from cec.envs.overcooked.dynamics import Sides, sides_of
from cec.envs.overcooked.state import POT_EMPTY, POT_READY
from cec.levels import DIR_VEC, GRID_SIZE, Item, Tile

SOON = 4  # steps: time to put an item down and take it again without leaving the counter (turns included)


@dataclass
class Handovers:
    """Counts of one episode (or summed over several); each per seat where a seat acts."""

    puts: np.ndarray
    taken: np.ndarray
    taken_back: np.ndarray
    pot_serves: np.ndarray
    passes: np.ndarray
    passes_taken: np.ndarray
    passes_taken_back: np.ndarray
    taken_back_soon: np.ndarray
    soups: int = 0

    @staticmethod
    def zero() -> Handovers:
        counts = {f.name: np.zeros(2, np.int64) for f in fields(Handovers) if f.name != "soups"}
        return Handovers(**counts, soups=0)

    def __add__(self, other: Handovers) -> Handovers:
        return Handovers(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))


def shared_counters(grid: np.ndarray, agent_pos: np.ndarray) -> np.ndarray:
    """bool[9, 9]: bare counters next to both seats' floor regions (where one can leave an item for the
    other); in a kitchen whose seats share a region, every counter they can reach."""
    return _shared(grid, sides_of(jnp.asarray(grid), jnp.asarray(agent_pos)))


def _shared(grid: np.ndarray, sides: Sides) -> np.ndarray:
    return (grid == Tile.COUNTER) & np.asarray(sides.counters).all(axis=0)


def facing_steps(states: Any) -> Iterator[tuple[int, int, int, int, int, int]]:
    """(t, seat, row, col, held before, held after) for every step t -> t + 1 of an episode's states and
    each seat: the cell it faces after the step (what an interact touched) and what it held either side;
    steps that face out of the frame are left out."""
    pos, facing = np.asarray(states.agent_pos), np.asarray(states.agent_dir)
    inv = np.asarray(states.agent_inv)
    for t in range(len(inv) - 1):
        for seat in (0, 1):
            r, c = (int(v) for v in pos[t + 1, seat] + DIR_VEC[int(facing[t + 1, seat])])
            if 0 <= r < GRID_SIZE and 0 <= c < GRID_SIZE:
                yield t, seat, r, c, int(inv[t, seat]), int(inv[t + 1, seat])


def count_handovers(states: Any) -> Handovers:
    """The hand-overs of one episode from its states (leading axis T, host arrays, each with its level)."""
    grid = np.asarray(states.level.grid[0])
    sides = sides_of(jnp.asarray(grid), jnp.asarray(states.level.agent_pos[0]))  # as the rewards read them
    shared, usable = _shared(grid, sides), np.asarray(sides.uses)
    items, pot = np.asarray(states.items), np.asarray(states.pot)
    out = Handovers.zero()
    owner: dict[tuple[int, int], tuple[int, bool, int]] = {}  # shared cell -> (whose item, a pass, when put)
    filled_by: dict[tuple[int, int], set[int]] = {}  # pot cell -> the seats that put onions in it
    for t, seat, r, c, before, after in facing_steps(states):
        cell = (r, c)
        if shared[r, c] and before != Item.NONE and after == Item.NONE and items[t + 1, r, c] == before:
            passed = not usable[seat, before] and usable[1 - seat, before]
            out.puts[seat] += 1
            out.passes[seat] += passed
            owner[cell] = (seat, passed, t)
        elif shared[r, c] and before == Item.NONE and after != Item.NONE and items[t, r, c] == after:
            if cell in owner:
                who, passed, when = owner.pop(cell)
                (out.taken if who != seat else out.taken_back)[seat] += 1
                out.taken_back_soon[seat] += who == seat and t - when <= SOON
                if passed:
                    (out.passes_taken if who != seat else out.passes_taken_back)[seat] += 1
        elif grid[r, c] == Tile.POT:
            if before == Item.ONION and after == Item.NONE and pot[t + 1, r, c] < pot[t, r, c]:
                filled_by.setdefault(cell, set()).add(seat)
            elif before == Item.PLATE and after == Item.DISH and pot[t, r, c] == POT_READY:
                if filled_by.pop(cell, set()) - {seat}:
                    out.pot_serves[seat] += 1
            elif pot[t + 1, r, c] == POT_EMPTY:
                filled_by.pop(cell, None)
        if before == Item.DISH and after == Item.NONE and grid[r, c] == Tile.GOAL:
            out.soups += 1
    return out


def pass_directions(h: Handovers, givers: tuple[str, str]) -> list[tuple[str, str, int, int, int]]:
    """The two directions of one episode's passes: (giver, receiver, passes, taken by the receiver, taken
    back by the giver), `givers` naming the players of seats 0 and 1 (a label each, e.g. `seed`, `cook`)."""
    return [
        (givers[s], givers[1 - s], int(h.passes[s]), int(h.passes_taken[1 - s]), int(h.passes_taken_back[s]))
        for s in (0, 1)
    ]


def summarise_directions(rows: list[tuple[str, str, int, int, int]]) -> dict[str, dict[str, float | None]]:
    """Per direction `giver -> receiver` over `pass_directions`' rows (one per giver seat and episode, so an
    episode of two seeds gives two `seed -> seed` rows): rows (`episodes`), passes per row, the share of rows
    with a pass, and the shares of the passes the receiver took and the giver took back (None where nothing
    was passed)."""
    out: dict[str, dict[str, Any]] = {}
    for giver, receiver, passes, taken, back in rows:
        d = out.setdefault(
            f"{giver} -> {receiver}", {"episodes": 0, "passes": 0, "with_pass": 0, "taken": 0, "back": 0}
        )
        d["episodes"] += 1
        d["passes"] += passes
        d["with_pass"] += passes > 0
        d["taken"] += taken
        d["back"] += back
    return {
        key: {
            "episodes": d["episodes"],
            "passes_per_episode": d["passes"] / d["episodes"],
            "share_with_a_pass": d["with_pass"] / d["episodes"],
            "share_taken": d["taken"] / d["passes"] if d["passes"] else None,
            "share_taken_back": d["back"] / d["passes"] if d["passes"] else None,
        }
        for key, d in out.items()
    }
