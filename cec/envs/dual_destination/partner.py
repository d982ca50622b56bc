"""The oracle partner: a scripted Dual Destination policy that best-responds to what its partner has shown.

`oracle_partner_step(memory, obs) -> (memory, action)` plays one seat from that seat's own observation
alone; `memory` (float32[MEMORY_SIZE], all zeros at an episode start) is all it keeps between steps. It is
pure and jittable, vmaps over envs and seats, and never reads the level, the state, the seat index or the
partner's actions: only what its observation shows, step after step (docs/dual_destination.md).

What it remembers (`PartnerMemory`, packed into the float vector):

    known      per cell, what it has seen there: unknown, no goal, green goal, pink goal (with the full
               view every cell is seen on every step; with the 3x3 view only the window's cells)
    last       the cell it last saw the partner on
    prev       the partner's cell on the previous step, if it saw the partner then
    belief     the goal cell it believes the partner is heading for
    predicted  where it expected the partner to be now (what an oracle partner with `belief` would do)
    mine       its own cell on the previous step
    intent     the cell it tried to enter on the previous step
    contested  whether it has refused to give up its own target to the partner before
    blocks     how many steps in a row its move was cancelled

Each step:

1. **Update the belief from the partner's behaviour** (only when the partner is in view and did not do
   what the belief predicted):
   - it moved: the belief stays if the move brought it closer to the believed cell, else it becomes the
     nearest goal cell the move brought it closer to (never the goal cell this seat stands on);
   - it tried to enter a cell and was stopped (the env cancels both moves when both agents head for one
     cell; or it stood still next to this seat): the goal cell that entering would have brought it
     closer to, this seat's own goal cell if it pushed into this seat standing on one;
   - it stays on a goal cell (or is first seen standing on one): that cell.
   Where the partner heads for this seat's own target, the nearer of the two keeps it (ties: the agent on
   the lower-numbered cell); but a partner that keeps coming after that gets it, so a stubborn partner is
   always followed.
2. **Default belief** (before the partner has revealed anything): the joint plan of the oracle. Over every
   known goal pair and both assignments of the two agents to its cells, the joint movement rule below is
   simulated from the current cells and the assignment that reaches a goal pair in the fewest steps is
   taken; this is the oracle's `T` (`oracle_plan`, tested on random levels). Ties are broken without
   knowing which seat is which (the observation does not say): green before pink, then the assignment
   that gives the lower-indexed cell of the agent on the lower-numbered cell. Both seats compute the same
   plan, so two oracle partners coordinate with each other exactly.
3. **Best response**: go to the other cell of the believed cell's pair. Without a belief (the partner
   never seen): the nearest cell of a known pair, green first; without a known pair: the nearest unseen
   cell (exploration; 3x3 view only).
4. **Move** along a shortest path. With the partner in view and a belief, by the joint rule: the agent
   farther from its target (ties: the one on the lower-numbered cell) moves first along the axis with
   more distance left; the other takes its other shortest direction, or waits one step, where both would
   enter one cell; an agent whose only way runs into a partner already standing on its goal steps aside.
   After a cancelled move: the other shortest direction if there is one, else the agent on the
   higher-numbered cell waits (either one after two cancellations in a row). A cancelled move also
   reveals an unseen partner: it can only stand on the cell beyond the one both wanted.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from cec.envs.dual_destination.env import OUTSIDE_WINDOW, Action, move
from cec.envs.dual_destination.level import DD_SIZE

NUM_CELLS = DD_SIZE * DD_SIZE
MEMORY_SIZE = 40  # floats: NUM_CELLS cells + 8 scalars, zero padded
UNKNOWN, EMPTY, GREEN, PINK = 0, 1, 2, 3  # codes of `PartnerMemory.known`
NONE = -1  # no cell
_SIM_STEPS = 2 * DD_SIZE + 6  # horizon of the plan simulation: longer than any joint plan on a 5x5 grid

_VEC = jnp.asarray([(-1, 0), (1, 0), (0, 1), (0, -1), (0, 0)], jnp.int32)  # per Action (STAY last)


class PartnerMemory(NamedTuple):
    """What the oracle partner carries between steps (cells are `row * 5 + col`, `NONE` = -1).

    Attributes:
        known: int32[25] what was seen on each cell: `UNKNOWN`, `EMPTY`, `GREEN` or `PINK`.
        last: int32[] the cell the partner was last seen on.
        prev: int32[] the partner's cell on the previous step (`NONE` if it was not seen then).
        belief: int32[] the goal cell the partner is believed to head for.
        predicted: int32[] where the partner was expected to be on this step.
        mine: int32[] this seat's own cell on the previous step.
        intent: int32[] the cell this seat tried to enter on the previous step (its own cell: it stayed).
        contested: int32[] 1 once this seat has kept its target although the partner headed for it.
        blocks: int32[] consecutive steps on which this seat's move was cancelled.
    """

    known: jax.Array
    last: jax.Array
    prev: jax.Array
    belief: jax.Array
    predicted: jax.Array
    mine: jax.Array
    intent: jax.Array
    contested: jax.Array
    blocks: jax.Array


def pack_memory(m: PartnerMemory) -> jax.Array:
    """float32[MEMORY_SIZE]; cells are stored plus one, so an all-zero vector is a fresh episode's memory."""
    cells = jnp.stack([m.last, m.prev, m.belief, m.predicted, m.mine, m.intent]) + 1
    flat = jnp.concatenate([m.known, cells, m.contested[None], m.blocks[None]]).astype(jnp.float32)
    return jnp.pad(flat, (0, MEMORY_SIZE - flat.shape[0]))


def unpack_memory(vec: jax.Array) -> PartnerMemory:
    """The inverse of `pack_memory` (float32[MEMORY_SIZE] -> `PartnerMemory`)."""
    v = jnp.round(vec).astype(jnp.int32)
    c = v[NUM_CELLS : NUM_CELLS + 6] - 1
    return PartnerMemory(
        v[:NUM_CELLS], c[0], c[1], c[2], c[3], c[4], c[5], v[NUM_CELLS + 6], v[NUM_CELLS + 7]
    )


def initial_memory() -> jax.Array:
    """float32[MEMORY_SIZE] zeros: nothing seen yet."""
    return jnp.zeros(MEMORY_SIZE, jnp.float32)


# ---------------------------------------------------------------------------------------------------
# GEOMETRY (cells are int32 scalars row * 5 + col)
# ---------------------------------------------------------------------------------------------------


def _rc(cell: jax.Array) -> jax.Array:
    return jnp.stack([cell // DD_SIZE, cell % DD_SIZE], axis=-1)


def _dist(a: jax.Array, b: jax.Array) -> jax.Array:
    """Manhattan distance between cells (broadcasts)."""
    return jnp.abs(a // DD_SIZE - b // DD_SIZE) + jnp.abs(a % DD_SIZE - b % DD_SIZE)


def _next(cell: jax.Array, action: jax.Array) -> jax.Array:
    rc = jnp.clip(_rc(cell) + _VEC[action], 0, DD_SIZE - 1)
    return rc[..., 0] * DD_SIZE + rc[..., 1]


def _prefs(x: jax.Array, g: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(first, second, n): the n (0-2) actions that bring cell `x` closer to cell `g`, the axis with more
    distance left first (ties: vertical); `second` equals `first` when n < 2, both STAY when n = 0."""
    dr = g // DD_SIZE - x // DD_SIZE
    dc = g % DD_SIZE - x % DD_SIZE
    v = jnp.where(dr > 0, Action.DOWN, Action.UP)
    h = jnp.where(dc > 0, Action.RIGHT, Action.LEFT)
    n = (dr != 0).astype(jnp.int32) + (dc != 0).astype(jnp.int32)
    v_first = (dr != 0) & (jnp.abs(dr) >= jnp.abs(dc))
    first = jnp.where(n == 0, Action.STAY, jnp.where(v_first, v, h))
    second = jnp.where(n == 2, jnp.where(v_first, h, v), first)
    return first.astype(jnp.int32), second.astype(jnp.int32), n


def _aside(x: jax.Array, blocked: jax.Array) -> jax.Array:
    """A step perpendicular to the blocked action that stays in the grid."""
    vertical = (blocked == Action.UP) | (blocked == Action.DOWN)
    r, c = x // DD_SIZE, x % DD_SIZE
    side = jnp.where(c > 0, Action.LEFT, Action.RIGHT)
    up_down = jnp.where(r > 0, Action.UP, Action.DOWN)
    return jnp.where(vertical, side, up_down).astype(jnp.int32)


def _ordered_moves(p: jax.Array, gp: jax.Array, q: jax.Array, gq: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Actions of the agent that moves first (`p`, target `gp`) and of the one that gives way (`q`)."""
    p1, p2, np_ = _prefs(p, gp)
    q1, q2, nq = _prefs(q, gq)
    q_must = jnp.where(nq == 1, _next(q, q1), jnp.where(nq == 0, q, NONE))  # the cell q has to take
    blocked = _next(p, p1) == q_must
    act_p = jnp.where(
        np_ == 0,
        Action.STAY,
        jnp.where(~blocked, p1, jnp.where(np_ == 2, p2, jnp.where(nq == 0, _aside(p, p1), p1))),
    ).astype(jnp.int32)
    p_into = _next(p, act_p)
    act_q = jnp.where(
        nq == 0,
        Action.STAY,
        jnp.where(
            _next(q, q1) != p_into, q1, jnp.where((nq == 2) & (_next(q, q2) != p_into), q2, Action.STAY)
        ),
    ).astype(jnp.int32)
    return act_p, act_q


def joint_moves(a: jax.Array, ga: jax.Array, b: jax.Array, gb: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The joint movement rule: actions of the agents on cells `a` and `b` heading for `ga` and `gb`.

    Symmetric: `joint_moves(b, gb, a, ga)` is the same pair of actions swapped, so two agents that agree
    on the targets agree on the moves whichever seat each one is.
    """
    da, db = _dist(a, ga), _dist(b, gb)
    a_first = (da > db) | ((da == db) & (a < b))
    fp, fq = _ordered_moves(
        jnp.where(a_first, a, b),
        jnp.where(a_first, ga, gb),
        jnp.where(a_first, b, a),
        jnp.where(a_first, gb, ga),
    )
    return jnp.where(a_first, fp, fq), jnp.where(a_first, fq, fp)


def plan_steps(a: jax.Array, ga: jax.Array, b: jax.Array, gb: jax.Array) -> jax.Array:
    """Joint steps until the agents on `a`, `b` stand on `ga`, `gb` under `joint_moves` and the env's
    movement rule (`_SIM_STEPS` if not within that horizon)."""

    def body(_: int, carry: tuple[jax.Array, jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array, jax.Array]:
        x, y, steps = carry
        done = (x == ga) & (y == gb)
        ax_, ay = joint_moves(x, ga, y, gb)
        pos = move(jnp.stack([_rc(x), _rc(y)]), jnp.stack([ax_, ay]))
        nx, ny = pos[0, 0] * DD_SIZE + pos[0, 1], pos[1, 0] * DD_SIZE + pos[1, 1]
        return jnp.where(done, x, nx), jnp.where(done, y, ny), steps + (~done).astype(jnp.int32)

    x, y, steps = jax.lax.fori_loop(0, _SIM_STEPS, body, (a, b, jnp.zeros((), jnp.int32)))
    return jnp.where((x == ga) & (y == gb), steps, _SIM_STEPS)


# ---------------------------------------------------------------------------------------------------
# THE POLICY
# ---------------------------------------------------------------------------------------------------


def _pair_cells(known: jax.Array, code: int) -> jax.Array:
    """int32[2]: the (up to) two cells known to hold `code`, ascending, `NONE` where unknown."""
    return jnp.nonzero(known == code, size=2, fill_value=NONE)[0].astype(jnp.int32)


def _nearest(origin: jax.Array, candidates: jax.Array, valid: jax.Array) -> jax.Array:
    """The valid candidate cell nearest to `origin` (ties: the lower cell index); `NONE` if none is valid."""
    key = jnp.where(valid, _dist(origin, candidates) * 64 + candidates, 1 << 20)
    return jnp.where(jnp.any(valid), candidates[jnp.argmin(key)], NONE)


def _other_cell(belief: jax.Array, pairs: jax.Array, pair_known: jax.Array) -> jax.Array:
    """The other cell of the known pair (`pairs` [2, 2]) that holds `belief`; `NONE` if there is none."""
    in_pair = (pairs == belief) & (belief != NONE)
    pair = jnp.argmax(jnp.any(in_pair, axis=1))
    other = jnp.where(in_pair[pair, 0], pairs[pair, 1], pairs[pair, 0])
    return jnp.where(jnp.any(in_pair) & pair_known[pair], other, NONE)


def _default_belief(me: jax.Array, partner: jax.Array, pairs: jax.Array, pair_known: jax.Array) -> jax.Array:
    """The partner's cell in the oracle's joint plan (see the module docstring), `NONE` without a pair."""
    # candidates: (pair, who gets cell 0) -> my cell, the partner's cell
    mine = jnp.stack([pairs[0, 0], pairs[0, 1], pairs[1, 0], pairs[1, 1]])
    theirs = jnp.stack([pairs[0, 1], pairs[0, 0], pairs[1, 1], pairs[1, 0]])
    valid = jnp.repeat(pair_known, 2)
    steps = jax.vmap(plan_steps, in_axes=(None, 0, None, 0))(me, mine, partner, theirs)
    lower_gets = jnp.where(me < partner, mine, theirs)  # the cell of the agent on the lower-numbered cell
    key = jnp.where(valid, steps * 4096 + jnp.repeat(jnp.arange(2), 2) * 64 + lower_gets, 1 << 24)
    return jnp.where(jnp.any(valid), theirs[jnp.argmin(key)], NONE)


def oracle_partner_step(memory: jax.Array, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
    """One step of the oracle partner for one seat.

    Long because it is the partner's rules one after another (what it remembers, where it walks), in one
    jitted function.

    Args:
        memory: float32[MEMORY_SIZE] from the previous step (zeros at an episode start).
        obs: float32[5, 5, 4] this seat's observation (channels: own agent, partner, green, pink; -1 in
            every channel outside a partial view).

    Returns:
        (memory for the next step, action int32[]).
    """
    m = unpack_memory(memory)
    flat = obs.reshape((NUM_CELLS, -1))
    cells = jnp.arange(NUM_CELLS, dtype=jnp.int32)
    visible = flat[:, 0] != OUTSIDE_WINDOW
    me = jnp.argmax(visible & (flat[:, 0] > 0.5)).astype(jnp.int32)
    here = visible & (flat[:, 1] > 0.5)
    seen = jnp.any(here)
    now = jnp.where(seen, jnp.argmax(here), NONE).astype(jnp.int32)
    code = jnp.where(flat[:, 2] > 0.5, GREEN, jnp.where(flat[:, 3] > 0.5, PINK, EMPTY))
    known = jnp.where(visible, code, m.known).astype(jnp.int32)
    pairs = jnp.stack([_pair_cells(known, GREEN), _pair_cells(known, PINK)])  # [2 pairs, 2 cells]
    pair_known = jnp.all(pairs != NONE, axis=1)
    goals = pairs.reshape(-1)
    goal_ok = (goals != NONE) & (goals != jnp.where(known[me] >= GREEN, me, NONE))

    # A BLOCKED MOVE: the env cancels both moves only when both agents head for one cell, so the partner
    # stood next to the cell this seat tried to enter; out of view, it can only be the cell beyond it.
    blocked = (m.intent != NONE) & (m.mine == me) & (m.intent != me)
    beyond_rc = 2 * _rc(m.intent) - _rc(me)
    beyond_ok = jnp.all((beyond_rc >= 0) & (beyond_rc < DD_SIZE))
    felt = blocked & ~seen & beyond_ok
    where_partner = jnp.where(seen, now, jnp.where(felt, beyond_rc[0] * DD_SIZE + beyond_rc[1], NONE))
    present = where_partner != NONE

    # 1. EVIDENCE: the partner did something the belief did not predict.
    belief = m.belief
    surprise = seen & ((m.predicted == NONE) | (now != m.predicted))
    # (a) it moved: towards the goal cells it came closer to (not the cell this seat stands on)
    moved = surprise & (m.prev != NONE) & (now != m.prev)
    closer = goal_ok & (_dist(now, goals) < _dist(m.prev, goals))
    # (b) it tried to enter a cell and was stopped: this seat's cell when both stood still side by side
    # (this seat stayed, the partner did not move although not on a goal), or the cell both headed for
    stood = (m.intent == me) & (m.mine == me) & seen & (m.prev == now) & (_dist(now, me) == 1)
    pushed = jnp.where(blocked, m.intent, jnp.where(stood & surprise & (known[now] < GREEN), me, NONE))
    pushed = jnp.where(present, pushed, NONE)
    toward = (goals != NONE) & (_dist(pushed, goals) < _dist(where_partner, goals))
    evidence_a = moved & ~jnp.any(closer & (goals == belief)) & jnp.any(closer)
    # pushing into this seat on a goal cell is taken as wanting that cell, whatever else it may head for
    into_me = (pushed == me) & (known[me] >= GREEN)
    evidence_b = (pushed != NONE) & jnp.any(toward) & (~jnp.any(toward & (goals == belief)) | into_me)
    revised = jnp.where(evidence_b, _nearest(pushed, goals, toward), _nearest(where_partner, goals, closer))
    evidence = evidence_a | evidence_b
    # heading for this seat's own target: who is nearer keeps it (ties: the lower-numbered cell), but a
    # partner that keeps coming after that gets it
    mine_before = _other_cell(m.belief, pairs, pair_known)
    d_partner, d_me = _dist(where_partner, revised), _dist(me, revised)
    yields = (d_partner < d_me) | ((d_partner == d_me) & (where_partner < me))
    contest = evidence & (revised == mine_before)
    accept = evidence & (~contest | yields | (m.contested > 0))
    belief = jnp.where(accept, revised, belief)
    contested = jnp.where(accept, 0, jnp.where(contest, 1, m.contested))
    # (c) it stands on a goal cell (stayed there, or first seen there)
    on_goal = (known[jnp.maximum(now, 0)] >= GREEN) & (now != me)
    settled = surprise & on_goal & ((m.prev == now) | ((m.prev == NONE) & (belief == NONE)))
    belief = jnp.where(settled, now, belief)

    # 2. DEFAULT: the oracle's joint plan, once a pair and the partner are known.
    partner = jnp.where(present, where_partner, m.last)
    plan = _default_belief(me, partner, pairs, pair_known)
    belief = jnp.where((belief == NONE) & (partner != NONE), plan, belief)

    # 3. TARGET: the other cell of the believed cell's pair.
    other = _other_cell(belief, pairs, pair_known)
    responds = other != NONE
    first_pair = jnp.where(pair_known[0], jnp.array([True, False]), pair_known)  # green before pink
    nearest_goal = _nearest(me, goals, (goals != NONE) & jnp.repeat(first_pair, 2))
    unseen = _nearest(me, cells, known == UNKNOWN)
    explore = jnp.where(belief != NONE, unseen, jnp.where(nearest_goal != NONE, nearest_goal, unseen))
    target = jnp.where(responds, other, explore)
    target = jnp.where(target == NONE, me, target)

    # 4. MOVE: the joint rule when the partner's cell is known now and a belief gives its target, else the
    # shortest way. After a blocked move it takes its other shortest direction if it has one, else the
    # seat on the higher-numbered cell waits one step (and either one after two blocked moves in a row).
    at = jnp.maximum(where_partner, 0)
    partner_target = jnp.where(belief != NONE, belief, at)
    mine_j, theirs_j = joint_moves(me, target, at, jnp.maximum(partner_target, 0))
    p1, p2, n = _prefs(me, target)
    alone = jnp.where((n == 2) & (_next(me, p1) == now), p2, p1)
    action = jnp.where(present & (belief != NONE), mine_j, alone)
    reroute = blocked & (_next(me, action) == m.intent) & (n == 2)
    action = jnp.where(reroute, jnp.where(action == p1, p2, p1), action)
    blocks = jnp.where(blocked, m.blocks + 1, 0)
    wait = blocked & ~reroute & present & ((me > where_partner) | (blocks >= 2))
    action = jnp.where(wait, Action.STAY, action).astype(jnp.int32)
    predicted = jnp.where(seen & (belief != NONE), _next(at, theirs_j), NONE)
    # the env cancels both moves when both agents head for one cell: predict that too
    predicted = jnp.where(seen & (predicted == _next(me, action)), now, predicted)

    new = PartnerMemory(
        known, partner, now, belief, predicted.astype(jnp.int32), me, _next(me, action), contested, blocks
    )
    return pack_memory(new), action
