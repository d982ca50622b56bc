"""Overcooked state, parameters, actions and step output types."""

from __future__ import annotations

import dataclasses
from enum import IntEnum
from typing import NamedTuple

import jax
from flax import struct

from cec.levels import Level

# Pot status, as in the paper's code: 23 empty, 22/21 one/two onions, 20 full (cooking starts at once),
# below 20 a countdown, 0 soup ready.
POT_EMPTY = 23
POT_FULL = 20
POT_READY = 0
MAX_ONIONS = 3
URGENCY_STEPS = 40  # the urgency channel turns on when fewer than this many steps remain
NUM_CHANNELS = 26
NUM_ACTIONS = 6


class Action(IntEnum):
    """Per-seat actions. Movement indices equal `Direction` indices (names match the movement)."""

    UP = 0  # north, row - 1
    DOWN = 1  # south, row + 1
    RIGHT = 2  # east, col + 1
    LEFT = 3  # west, col - 1
    STAY = 4
    INTERACT = 5


@struct.dataclass
class EnvParams:
    """Traced (vmappable) dynamics settings. Defaults are those of the paper's code.

    Attributes:
        max_steps: episode length; `done` when `time >= max_steps` (400 as in Overcooked-AI; the paper's
            CEC runs use 100, its evaluation 256).
        delivery_reward: team (sparse) reward per delivered soup, paid to both seats.
        onion_in_pot_reward: shaped reward to the seat that puts an onion in a pot.
        soup_pickup_reward: shaped reward to the seat that plates a ready soup.
        plate_pickup_reward: shaped reward to the seat that picks up a plate while no loose plate lies
            on a counter and fewer plates are in hands than pots hold onions or soup.
        random_start_facing: if true, `reset` draws each seat's facing uniformly (as the paper's code);
            otherwise it uses the level's `agent_dir`.
        handover_reward: shaped reward to *both* seats each time a seat uses an item it could not have
            fetched itself, so the partner must have handed it over: an onion into a pot, or a soup plated,
            by a seat whose floor region reaches no onion pile; a soup plated by one whose region reaches
            no plate pile; a soup delivered by one whose region reaches no pot. Each use consumes the item,
            so it cannot be farmed by passing an item back and forth. 0 (the default, and the paper's):
            off, and nothing of it is computed. Not in the paper: a lever of docs/reproduce_overcooked.md.
        random_start_items: the probability with which, at the start of an episode, each counter beside the
            floor holds an onion and each seat holds an onion or a plate (uniformly): states the seats
            rarely reach by themselves, such as an onion already lying on the counter between them, are where
            episodes begin. No plated soup, full or cooking pot is drawn: a soup for free teaches fetching
            it, not cooking (measured: docs/reproduce_overcooked.md, lever (g)); onions, not plates, on the
            counters, as a loose plate there switches the plate-pickup shaping off. 0 (the default, and the
            paper's): empty counters and hands, and nothing of it is drawn. A training lever only
            (`without_training_levers` turns it off for evaluation). Not in the paper; Overcooked-AI's
            random start states are the same idea.
        random_start_pot_onions: the probability with which each pot starts an episode holding one or two
            onions (equally likely; never cooking, never a soup), so that fewer onions must reach it for a
            soup: in a kitchen that needs a hand-over, one exchange across the counter can complete a pot.
            Drawn apart from `random_start_items` (its draws stay as they were). 0 (the default, and the
            paper's): empty pots. A training lever only, off in evaluation. Not in the paper.
        pass_reward: shaped reward to the seat that puts an item on a counter where only its partner can
            use it: the seat itself cannot (an onion or a plate by a seat whose floor region reaches no pot,
            a plated soup by one that reaches no goal), the partner can, and the counter is next to the
            partner's region. The giver's half of a hand-over, paid when it happens; taking such an item
            back off such a counter costs the same, so putting an item down and picking it up again earns
            nothing. 0 (the default, and the paper's): off, and nothing of it is computed. A training lever
            only, off in evaluation. Not in the paper: a lever of docs/reproduce_overcooked.md.
        pass_take_back_cost: what taking such an item back costs beyond `pass_reward`, so that putting an
            item down and picking it up again costs this much instead of nothing (with a discount below 1
            the symmetric loop even pays a little: the reward comes before the cost). 0 (the default):
            the cost is `pass_reward`. A training lever only, off in evaluation. Not in the paper.
        pass_taken_reward: shaped reward to a seat when its partner takes up such an item (one the
            partner can use and the seat cannot, off a counter next to the seat's region): the giver is
            paid when the exchange completes, not when it puts the item down, so putting an item down and
            taking it up again earns nothing by construction. Which seat put the item there is not
            tracked: an onion that random start items laid on such a counter pays too. 0 (the default,
            and the paper's): off. A training lever only, off in evaluation. Not in the paper.
        pass_received_reward: shaped reward to the receiver of such an exchange: a seat that takes up an
            item only it can use (as `pass_reward` counts it, seen from the other side) off a counter next
            to its partner's region is paid at once; putting such an item back on such a counter costs the
            same, so taking an item up and putting it down again earns nothing. The receiver's half of a
            hand-over, which otherwise pays only when the item is used. Which seat put the item there is
            not tracked (a random start onion on such a counter pays too). 0 (the default, and the
            paper's): off. A training lever only, off in evaluation. Not in the paper.
    """

    max_steps: int = 400
    delivery_reward: float = 20.0
    onion_in_pot_reward: float = 10.0
    soup_pickup_reward: float = 15.0
    plate_pickup_reward: float = 3.0
    random_start_facing: bool = True
    handover_reward: float = 0.0
    random_start_items: float = 0.0
    random_start_pot_onions: float = 0.0
    pass_reward: float = 0.0
    pass_take_back_cost: float = 0.0
    pass_taken_reward: float = 0.0
    pass_received_reward: float = 0.0

    def without_training_levers(self) -> EnvParams:
        """These settings as evaluation plays them: the training-only levers (`handover_reward`,
        `pass_reward`, `pass_take_back_cost`, `pass_taken_reward`, `pass_received_reward`,
        `random_start_items`, `random_start_pot_onions`) off;
        everything the score depends on (episode length, rewards) kept."""
        return dataclasses.replace(
            self,
            handover_reward=0.0,
            pass_reward=0.0,
            pass_take_back_cost=0.0,
            pass_taken_reward=0.0,
            pass_received_reward=0.0,
            random_start_items=0.0,
            random_start_pot_onions=0.0,
        )


class EnvState(struct.PyTreeNode):
    """Everything that changes during an episode, plus the level being played.

    Attributes:
        level: the kitchen (static during the episode).
        agent_pos: int32[2, 2] `(row, col)` per seat.
        agent_dir: int32[2] facing per seat (`Direction`).
        agent_inv: int32[2] held `Item` per seat.
        items: uint8[9, 9] loose `Item` lying on each counter cell.
        pot: uint8[9, 9] pot status on pot cells (see `POT_*`), 0 elsewhere.
        time: int32 steps taken in this episode.
        episode: int32 index of this episode in the env's life (auto-reset plays buffer[episode % K]).
    """

    level: Level
    agent_pos: jax.Array
    agent_dir: jax.Array
    agent_inv: jax.Array
    items: jax.Array
    pot: jax.Array
    time: jax.Array
    episode: jax.Array


class StepOutput(NamedTuple):
    """What `step` returns.

    Attributes:
        obs: uint8[2, 9, 9, 26] each seat's observation from its own perspective.
        state: the next `EnvState` (after auto-reset, for `step_autoreset`).
        reward: float32[] team sparse reward of this step (the same for both seats).
        shaped_reward: float32[2] per-seat shaped reward of this step (unscaled).
        done: bool[] the episode ended with this step.
        collision: bool[] a move was cancelled because both seats wanted the same cell or to swap.
    """

    obs: jax.Array
    state: EnvState
    reward: jax.Array
    shaped_reward: jax.Array
    done: jax.Array
    collision: jax.Array
