"""Dual Destination levels as data: the `DDLevel` type, the paper's tasks, validation and the generator.

A level is the 5x5 grid's four or six special cells: both agents' start cells, the two green goals and,
for the multi-task variant, the two pink goals. There are no walls. Coordinates are `(row, col)` with
row 0 at the top; the reference code writes positions as `(x, y) = (col, row)`.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from cec.levels import LevelError

DD_SIZE = 5
NO_CELL = -1  # the pink cells of a level without pink goals


@struct.dataclass
class DDLevel:
    """A Dual Destination task. All fields are arrays so that levels stack into batches and pass `jit`.

    Attributes:
        agent_pos: int32[2, 2] start cell `(row, col)` of seat 0 and seat 1.
        green_goals: int32[2, 2] the two green goal cells `(row, col)`.
        pink_goals: int32[2, 2] the two pink goal cells `(row, col)`; `(-1, -1)` when `has_pink` is false.
        has_pink: bool[] whether the level has pink goals. Pink goals take part in the game (reward and
            observation channel 3) only when this is true *and* `DDParams.multi_task` is true.
    """

    agent_pos: jax.Array
    green_goals: jax.Array
    pink_goals: jax.Array
    has_pink: jax.Array

    @classmethod
    def create(
        cls,
        agent_pos: np.ndarray | Sequence[Sequence[int]],
        green_goals: np.ndarray | Sequence[Sequence[int]],
        pink_goals: np.ndarray | Sequence[Sequence[int]] | None = None,
    ) -> DDLevel:
        """Builds a level from `(row, col)` cells, validating them (raises `LevelError`).

        Args:
            agent_pos: 2 start cells, seat 0 first.
            green_goals: 2 green goal cells.
            pink_goals: 2 pink goal cells, or None for a level without pink goals.
        """
        has_pink = pink_goals is not None
        raw_pink = np.asarray(pink_goals) if has_pink else np.full((2, 2), NO_CELL)
        raw = (np.asarray(agent_pos), np.asarray(green_goals), raw_pink)
        # Validate the raw inputs, before an int32 cast could wrap out-of-range values.
        _validate(*raw, np.asarray(has_pink))
        return cls(
            agent_pos=jnp.asarray(raw[0], jnp.int32),
            green_goals=jnp.asarray(raw[1], jnp.int32),
            pink_goals=jnp.asarray(raw[2], jnp.int32),
            has_pink=jnp.asarray(has_pink),
        )


def fixed_level() -> DDLevel:
    """The paper's fixed task (Figure "Dual Destination Problem" (a)), as in the reference's fixed reset.

    Agents at the middle of the left and right edges, green goals at the middle of the top and bottom
    edges (4 moves from each agent), pink goals one step inside the green ones (3 moves from each agent).
    The pink goals matter only with `DDParams(multi_task=True)`; the paper's single-task results ignore
    them.

        . . G . .
        . . p . .
        0 . . . 1
        . . p . .
        . . G . .
    """
    return DDLevel.create(
        agent_pos=[(2, 0), (2, 4)], green_goals=[(0, 2), (4, 2)], pink_goals=[(1, 2), (3, 2)]
    )


def multi_task_level() -> DDLevel:
    """The reference's "multiple" task (`incentivize_strat=3`), the paper's multi-task fixed task.

    Reference `(x, y)` positions green (1,0), (3,4) and pink (1,4), (3,1) are `(row, col)` (0,1), (4,3)
    and (4,1), (1,3); the agents start as in `fixed_level`. The quickest green and pink pairings both
    take 3 steps.

        . G . . .
        . . . p .
        0 . . . 1
        . . . . .
        . p . G .
    """
    return DDLevel.create(
        agent_pos=[(2, 0), (2, 4)], green_goals=[(0, 1), (4, 3)], pink_goals=[(4, 1), (1, 3)]
    )


def stack_dd_levels(levels: Sequence[DDLevel]) -> DDLevel:
    """Stacks levels into one batched `DDLevel` (leading axis = level index)."""
    if not levels:
        raise LevelError("cannot stack an empty sequence of Dual Destination levels")
    return jax.tree.map(lambda *xs: jnp.stack(xs), *levels)


HELDOUT_GENERATED_SEED = 20250601  # the seed of the held-out generated evaluation tasks
NUM_HELDOUT_GENERATED = 100


@functools.cache
def _heldout_generated_cells() -> np.ndarray:
    """int64[100, 6, 2]: agents, green goals, pink goals of each held-out generated task (NumPy's PCG64,
    so the set does not depend on the JAX version)."""
    rng = np.random.default_rng(HELDOUT_GENERATED_SEED)
    with jax.ensure_compile_time_eval():  # concrete even when first called inside a trace
        fixed = _fixed_tasks()
    taken = {_task_key(np.asarray(lv.agent_pos), np.asarray(lv.green_goals)) for lv in fixed}
    out: list[np.ndarray] = []
    while len(out) < NUM_HELDOUT_GENERATED:
        idx = rng.permutation(DD_SIZE * DD_SIZE)[:6]
        cells = np.stack([idx // DD_SIZE, idx % DD_SIZE], axis=-1)
        key = _task_key(cells[0:2], cells[2:4])
        if key not in taken:  # a new task even without its pink goals (the single-task game ignores them)
            taken.add(key)
            out.append(cells)
    return np.stack(out)


def _task_key(agents: np.ndarray, green: np.ndarray) -> tuple[frozenset, frozenset]:
    return frozenset(map(tuple, agents.tolist())), frozenset(map(tuple, green.tolist()))


def _fixed_tasks() -> list[DDLevel]:
    return [fixed_level(), multi_task_level()]


def heldout_generated_dd_levels() -> list[tuple[str, DDLevel]]:
    """The 100 held-out generated evaluation tasks, `generated_000` .. `generated_099`, in order.

    Drawn like `generate_dd_level(key, multi_task=True, ...)` (six distinct uniform cells) from a fixed
    seed; each is a different task from the others and from the two fixed tasks even with its pink goals
    ignored, so the same 100 levels serve the single-task game (pink ignored) and the multi-task one.
    """
    return [
        (f"generated_{i:03d}", DDLevel.create(c[0:2], c[2:4], c[4:6]))
        for i, c in enumerate(_heldout_generated_cells())
    ]


def held_out_dd_levels() -> DDLevel:
    """The tasks procedural training must never produce (K = 102): `fixed_level()`, `multi_task_level()`
    and the 100 held-out generated evaluation tasks (`heldout_generated_dd_levels`).

    Pass this as `exclude` to `generate_dd_level`.
    """
    return _held_out_stack()


@functools.cache
def _held_out_stack() -> DDLevel:
    with jax.ensure_compile_time_eval():  # concrete even when first called inside a trace
        generated = [lv for _, lv in heldout_generated_dd_levels()]
        return jax.tree.map(_read_only, stack_dd_levels([*_fixed_tasks(), *generated]))


def _read_only(x: jax.Array) -> np.ndarray:
    out = np.array(x)
    out.flags.writeable = False  # cached and shared: nobody may change it
    return out


# ---------------------------------------------------------------------------------------------------
# VALIDATION
# ---------------------------------------------------------------------------------------------------


def validate_dd_level(level: DDLevel) -> None:
    """Checks a concrete level, single or batched (leading axes), and raises `LevelError` naming the problem.

    Checks: shapes, integer cells inside the 5x5 grid, and all cells distinct (the two agents, the two
    green goals and, when `has_pink`, the two pink goals). The pink cells of a level without pink goals
    are ignored.
    """
    _validate(
        np.asarray(level.agent_pos),
        np.asarray(level.green_goals),
        np.asarray(level.pink_goals),
        np.asarray(level.has_pink),
    )


_CELL_NAMES = ("agent 0", "agent 1", "green goal 0", "green goal 1", "pink goal 0", "pink goal 1")


def _validate(agents: np.ndarray, green: np.ndarray, pink: np.ndarray, has_pink: np.ndarray) -> None:
    batch = agents.shape[:-2]
    for name, arr in (("agent_pos", agents), ("green_goals", green), ("pink_goals", pink)):
        if arr.shape[-2:] != (2, 2) or arr.shape[:-2] != batch:
            raise LevelError(
                f"{name} must have shape (..., 2, 2): two (row, col) cells, got {arr.shape} "
                f"(agent_pos has {agents.shape})"
            )
        if not np.issubdtype(arr.dtype, np.integer):
            raise LevelError(f"{name} must hold integer (row, col) cells, got dtype {arr.dtype}")
    if has_pink.shape != batch or has_pink.dtype != np.bool_:
        raise LevelError(
            f"has_pink must be a bool array of shape {batch}, got {has_pink.dtype}{has_pink.shape}"
        )
    cells = np.concatenate([agents, green, pink], axis=-2).reshape(-1, 6, 2)
    present = np.ones((cells.shape[0], 6), bool)
    present[:, 4:] = has_pink.reshape(-1, 1)

    def where(i: int) -> str:
        if not batch:
            return ""
        index = tuple(int(v) for v in np.unravel_index(i, batch))
        return f"level {index[0] if len(index) == 1 else index}: "

    outside = present & np.any((cells < 0) | (cells >= DD_SIZE), axis=-1)
    if outside.any():
        i, j = np.argwhere(outside)[0]
        raise LevelError(
            f"{where(i)}{_CELL_NAMES[j]} cell {tuple(cells[i, j].tolist())} lies outside the "
            f"{DD_SIZE}x{DD_SIZE} grid; rows and columns run 0..{DD_SIZE - 1}"
        )
    same = np.all(cells[:, :, None] == cells[:, None, :], axis=-1)  # (N, 6, 6)
    same &= present[:, :, None] & present[:, None, :] & ~np.eye(6, dtype=bool)
    if same.any():
        i, j, k = np.argwhere(same)[0]
        raise LevelError(
            f"{where(i)}{_CELL_NAMES[j]} and {_CELL_NAMES[k]} share the cell {tuple(cells[i, j].tolist())}; "
            "agents and goals must all lie on distinct cells"
        )


# ---------------------------------------------------------------------------------------------------
# SAME TASK AND GENERATOR
# ---------------------------------------------------------------------------------------------------


def _same_pair(a: jax.Array, b: jax.Array) -> jax.Array:
    """bool[K]: the cell pair `a` (2, 2) equals `b` (K, 2, 2) as a set (either order)."""
    straight = jnp.all(a == b, axis=(-1, -2))
    crossed = jnp.all(a[::-1] == b, axis=(-1, -2))
    return straight | crossed


def same_dd_task(level: DDLevel, others: DDLevel) -> jax.Array:
    """Whether `level` is the same task as each of `others`, up to relabelling seats and goals.

    Two levels are the same task when their start cells, green goals and, if both have pink goals, pink
    goals are equal as sets. Swapping the seats gives the same task because both seats see egocentric
    observations and share one policy; swapping two goals of a colour changes nothing at all.

    Args:
        level: a single level.
        others: a batched level with leading axis K.

    Returns:
        bool[K].
    """
    pink_equal = _same_pair(level.pink_goals, others.pink_goals) | ~(level.has_pink & others.has_pink)
    return (
        _same_pair(level.agent_pos, others.agent_pos)
        & _same_pair(level.green_goals, others.green_goals)
        & pink_equal
    )


def _draw(key: jax.Array, multi_task: bool | jax.Array) -> DDLevel:
    # Six distinct uniform cells, drawn without replacement: the i-th is the r-th still-free cell with r
    # uniform in 0..24-i. The first 4 alone are 4 distinct uniform cells (the single-task level).
    n_cells = DD_SIZE * DD_SIZE
    ranks = jax.random.randint(key, (6,), 0, n_cells - jnp.arange(6))
    free = jnp.ones((n_cells,), bool)
    picks = []
    for r in ranks:
        idx = jnp.argmax(free & (jnp.cumsum(free) - 1 == r))
        free = free & (jnp.arange(n_cells) != idx)
        picks.append(idx)
    idx = jnp.stack(picks)
    cells = jnp.stack([idx // DD_SIZE, idx % DD_SIZE], axis=-1).astype(jnp.int32)  # (6, 2)
    has_pink = jnp.asarray(multi_task, bool)
    return DDLevel(
        agent_pos=cells[0:2],
        green_goals=cells[2:4],
        pink_goals=jnp.where(has_pink, cells[4:6], NO_CELL),
        has_pink=has_pink,
    )


def generate_dd_level(key: jax.Array, multi_task: bool | jax.Array, exclude: DDLevel | None) -> DDLevel:
    """Draws a procedural task: agents and goals on distinct uniformly random cells, never an excluded task.

    Pure and jittable; vmap over `key` for a batch (`in_axes=(0, None, None)`). While the draw is the
    same task as any level in `exclude` (see `same_dd_task`), it draws again with a fresh key: the check
    is exhaustive, not a single retry. It terminates as long as `exclude` leaves some task out.

    Args:
        key: PRNG key.
        multi_task: draw pink goals too (6 distinct cells instead of 4); a bool or a traced bool[].
        exclude: a batched `DDLevel` with leading axis K (e.g. `held_out_dd_levels()`), or None.

    Returns:
        a single `DDLevel`.
    """

    def excluded(level: DDLevel) -> jax.Array:
        if exclude is None:
            return jnp.asarray(False)
        return jnp.any(same_dd_task(level, exclude))

    key, sub = jax.random.split(key)
    first = _draw(sub, multi_task)

    def body(carry: tuple[jax.Array, DDLevel]) -> tuple[jax.Array, DDLevel]:
        k, _ = carry
        k, sub = jax.random.split(k)
        return k, _draw(sub, multi_task)

    _, level = jax.lax.while_loop(lambda c: excluded(c[1]), body, (key, first))
    return level
