"""Where an episode's time goes: what each seat carries, which chores of a soup it does, and how long the
finished soups wait (docs/reproduce_overcooked.md, "Why Counter Circuit fails").

A soup is a chain of chores: three onions from a pile into a pot, the pot cooks, a plate from its pile
to the finished pot, the plated soup to a delivery window. Read from a played episode's states (`cec.
evaluation.crossplay.episode_states`), host-side, per seat:

    carrying        steps spent holding nothing, an onion, a plate, a plated soup (`Item` order)
    still           steps a seat neither moved nor changed what it holds
    onions_taken    onions taken from a pile
    onions_in       onions put in a pot
    plates_taken    plates taken from a pile
    soups_plated    finished soups put on a plate at the pot
    soups           soups delivered
    put_down        items put down on a bare counter
    soups_put_down  such items that were plated soups (a soup parked on the way to the window)
    taken_back_soon such items picked up again by the same seat within `SOON` steps (put down and taken
                    at once: dithering, not leaving the item for later or for the partner)

and per episode: `soups_ready`, pots that finished cooking, and `ready_wait`, the steps a finished soup
stood in its pot (summed over pots) before a plate took it. A kitchen whose soups cook but wait, with
plates seldom taken, stalls at the plates; one whose seats carry onions while pots take none stalls on
the way to the pots.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from cec.envs.overcooked.state import POT_READY
from cec.evaluation.handovers import SOON, facing_steps
from cec.levels import Item, Tile

PER_SEAT = (
    "onions_taken",
    "onions_in",
    "plates_taken",
    "soups_plated",
    "soups",
    "put_down",
    "soups_put_down",
    "taken_back_soon",
)


@dataclass
class Chores:
    """Counts of one episode (or summed over several); `carrying` is int[2 seats, 4 items], the per-seat
    counts int[2], the pot counts scalars."""

    carrying: np.ndarray
    still: np.ndarray
    onions_taken: np.ndarray
    onions_in: np.ndarray
    plates_taken: np.ndarray
    soups_plated: np.ndarray
    soups: np.ndarray
    put_down: np.ndarray
    soups_put_down: np.ndarray
    taken_back_soon: np.ndarray
    soups_ready: int = 0
    ready_wait: int = 0

    @staticmethod
    def zero() -> Chores:
        seats = {name: np.zeros(2, np.int64) for name in ("still", *PER_SEAT)}
        return Chores(carrying=np.zeros((2, len(Item)), np.int64), **seats, soups_ready=0, ready_wait=0)

    def __add__(self, other: Chores) -> Chores:
        return Chores(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))

    def per_episode(self, episodes: int) -> dict[str, Any]:
        """Both seats together, per episode; `carrying` as shares of the seats' steps, by item name."""
        steps = max(int(self.carrying.sum()), 1)
        out: dict[str, Any] = {
            "carrying": {item.name.lower(): float(self.carrying[:, item].sum()) / steps for item in Item},
            "still": float(self.still.sum()) / steps,
        }
        for name in (*PER_SEAT, "soups_ready", "ready_wait"):
            out[name] = float(np.sum(getattr(self, name))) / max(episodes, 1)
        return out


def count_chores(states: Any) -> Chores:
    """The chores of one episode from its states (leading axis T, host arrays, each with its level)."""
    grid = np.asarray(states.level.grid[0])
    pos, inv = np.asarray(states.agent_pos), np.asarray(states.agent_inv)
    items, pot = np.asarray(states.items), np.asarray(states.pot)
    out = Chores.zero()
    for seat in (0, 1):
        out.carrying[seat] = np.bincount(inv[:-1, seat], minlength=len(Item))
    kept = inv[1:] == inv[:-1]  # (T - 1, 2): held the same thing over the step
    out.still[:] = (kept & (pos[1:] == pos[:-1]).all(-1)).sum(0)
    ready = (pot == POT_READY) & (grid == Tile.POT)[None]
    out.soups_ready = int((ready[1:] & ~ready[:-1]).sum())
    out.ready_wait = int(ready[:-1].sum())
    put_at: dict[tuple[int, int], tuple[int, int]] = {}  # counter cell -> (the seat that put an item, when)
    for t, seat, r, c, before, after in facing_steps(states):
        if before == after:
            continue
        tile = grid[r, c]
        if tile == Tile.ONION_PILE and after == Item.ONION:
            out.onions_taken[seat] += 1
        elif tile == Tile.PLATE_PILE and after == Item.PLATE:
            out.plates_taken[seat] += 1
        elif tile == Tile.POT and before == Item.ONION:
            out.onions_in[seat] += 1
        elif tile == Tile.POT and before == Item.PLATE and after == Item.DISH:
            out.soups_plated[seat] += 1
        elif tile == Tile.GOAL and before == Item.DISH:
            out.soups[seat] += 1
        elif tile == Tile.COUNTER and after == Item.NONE and items[t + 1, r, c] == before:
            out.put_down[seat] += 1
            out.soups_put_down[seat] += before == Item.DISH
            put_at[(r, c)] = (seat, t)
        elif tile == Tile.COUNTER and before == Item.NONE and (r, c) in put_at:
            who, when = put_at.pop((r, c))
            out.taken_back_soon[seat] += who == seat and t - when <= SOON
    return out
