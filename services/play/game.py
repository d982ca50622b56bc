"""The game on the server: kitchens from level specs, partners from checkpoints, and a round stepped one
human action at a time with the agent's LSTM state carried.

Latency. Every round keeps the agent's action for the *current* state ready (it depends only on what the
agent sees, not on the human's next key) and the six next states the human's six actions lead to (one
vmapped env step). A turn-based client gets those six as compact JSON and draws the chosen one the moment
a key goes down; the server then commits that branch, runs the agent on the new observation and prepares
the next six, all in one jitted call (`_advance`). A real-time tick commits the branch of the human's
latest key (STAY without one). The env functions are compiled once; the agent's once per network
architecture (parameters are arguments, so every checkpoint of one architecture shares the compile).

Compact state (what the browser draws and what the records keep for every step), JSON:

    {"t": 12, "pos": [[r, c], [r, c]], "dir": [d0, d1], "inv": [i0, i1],
     "items": [[r, c, item], ...], "pots": [[r, c, status], ...]}

with `dir` the `Direction` codes (0 N, 1 S, 2 E, 3 W), `inv`/`item` the `Item` codes (0 none, 1 onion,
2 plate, 3 dish) and `status` the pot status of `cec.envs.overcooked.state` (23 empty .. 20 full, counting
down to 0 ready). Together with the round's level (ASCII in the records) it determines the `EnvState`
(`expand_state`, its inverse).

Size: the compiled round (`_advance`), its host-side driver and the compact-state codec the browser and
the records share change together; the study flow and recording are their own modules.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cec import checkpoints
from cec.agents.bundle import is_url
from cec.agents.network import (
    ActorCritic,
    LSTMState,
    NetworkConfig,
    empty_history,
    forward,
    network_preset,
    push_history,
    select_action,
)
from cec.agents.policy import Policy, load_policies, load_policy, random_policy
from cec.agents.zoo import ZooEntry, load_zoo
from cec.config import ConfigError
from cec.envs import overcooked as oc
from cec.envs.task import EnvConfig
from cec.levels import DIR_VEC, GRID_SIZE, Direction, Item, Level, Tile
from cec.levels.classic import classic_level
from services.play.config import PartnerSpec, StudyConfig

log = logging.getLogger("cec.play")

NUM_ACTIONS = oc.NUM_ACTIONS
STAY = int(oc.Action.STAY)


# ---------------------------------------------------------------------------------------------------------
# LEVELS
# ---------------------------------------------------------------------------------------------------------


def level_json(level: Level) -> dict[str, Any]:
    """The static kitchen for the browser: {"h", "w", "grid": rows of `Tile` codes}."""
    kitchen = level.kitchen()
    return {"h": int(kitchen.shape[0]), "w": int(kitchen.shape[1]), "grid": kitchen.astype(int).tolist()}


# ---------------------------------------------------------------------------------------------------------
# PARTNERS
# ---------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PartnerPool:
    """The policies one partner condition draws from (one for a checkpoint, a zoo group's several)."""

    spec: PartnerSpec
    policies: tuple[Policy, ...]

    def eligible(self, level_spec: str) -> list[int]:
        """Indices of the policies that play `level_spec` (single-task agents only their own kitchens)."""
        return [i for i, p in enumerate(self.policies) if p.levels is None or level_spec in p.levels]


def _relative_to(base_dir: Path, source: str) -> Path | str:
    """A study's checkpoint or zoo path (relative to the study's folder), or a shipped name or a bundle's
    http(s) URL as it is (`load_zoo` fetches the bundle)."""
    if is_url(source):
        return source
    path = Path(source)
    if path.is_absolute() or (base_dir / path).exists() or source != path.name:
        return path if path.is_absolute() else base_dir / path
    return path  # `shipped`, or a shipped policy's name: resolved by load_zoo / resolve_checkpoint


def load_partner(spec: PartnerSpec, base_dir: Path) -> PartnerPool:
    """Loads a partner condition's policies. `ConfigError` naming the partner and the cause on failure."""
    where = f"partner {spec.name!r}"
    if spec.random_init:
        env = EnvConfig()
        network = network_preset(spec.network, "overcooked")
        policy = random_policy(
            spec.name, jax.random.PRNGKey(spec.init_seed), env=env, network=network, seed=spec.init_seed
        )
        return PartnerPool(spec, (policy,))
    if spec.checkpoint:
        path = _relative_to(base_dir, spec.checkpoint)
        try:
            policy = load_policy(ZooEntry(spec.name, str(path), seed=spec.seed))
        except (checkpoints.CheckpointError, OSError, ValueError) as err:
            raise ConfigError(f"{where}: {err}") from err
        policies: tuple[Policy, ...] = (policy,)
    else:
        path = _relative_to(base_dir, spec.zoo)
        entries = load_zoo(path)
        loaded, skipped = load_policies(entries)
        for s in skipped:
            log.warning("%s: zoo entry %s skipped: %s", where, s.name, s.reason)
        policies = tuple(p for p in loaded if not spec.group or spec.group in (p.algorithm, p.name))
        if not policies:
            groups = sorted({p.algorithm for p in loaded})
            raise ConfigError(
                f"{where}: zoo {str(path)!r} has no loadable entry of group {spec.group!r} "
                f"(groups there: {groups}; entries: {[p.name for p in loaded]}; "
                f"skipped: {[s.name for s in skipped]})"
            )
    for p in policies:
        if p.env.name != "overcooked":  # the study plays in an Overcooked kitchen (this module renders it)
            raise ConfigError(
                f"{where}: policy {p.name!r} plays {p.env.name}; only Overcooked agents can be played"
            )
    return PartnerPool(spec, policies)


# ---------------------------------------------------------------------------------------------------------
# JITTED STEP FUNCTIONS
# ---------------------------------------------------------------------------------------------------------


class Prepared(NamedTuple):
    """What a round keeps on the device between steps.

    Attributes:
        branches: `StepOutput` with a leading axis of 6: the step for each human action (the agent's
            action fixed to `agent_action`).
        lstm: the agent's LSTM carry after seeing the current observation, [1, H] leaves.
        history: int32[1, 1, K] the human's last K actions as the agent saw them (E3T's partner model).
        agent_action: int32[] the agent's action in the current state.
        bumps: int32[] the steps in a row up to the current state whose moves were cancelled by a collision.
        gives_way: bool[] `agent_action` is a step aside chosen by the give-way rule, not its policy's own.
    """

    branches: oc.StepOutput
    lstm: LSTMState
    history: jax.Array
    agent_action: jax.Array
    bumps: jax.Array
    gives_way: jax.Array


def _joint(human: jax.Array, agent: jax.Array, agent_seat: jax.Array) -> jax.Array:
    """int32[2] actions by seat."""
    return jnp.where(agent_seat == 0, jnp.stack([agent, human]), jnp.stack([human, agent])).astype(jnp.int32)


def _branches(
    state: oc.EnvState, agent_action: jax.Array, agent_seat: jax.Array, params: oc.EnvParams
) -> oc.StepOutput:
    key = jax.random.PRNGKey(0)  # the dynamics are deterministic
    humans = jnp.arange(NUM_ACTIONS, dtype=jnp.int32)
    out: oc.StepOutput = jax.vmap(lambda h: oc.step(key, state, _joint(h, agent_action, agent_seat), params))(
        humans
    )
    return out


def act(
    network: ActorCritic,
    params: Any,
    lstm: LSTMState,
    obs: jax.Array,
    first: jax.Array,
    history: jax.Array,
    key: jax.Array,
    greedy: bool,
    allowed: jax.Array | None = None,
) -> tuple[LSTMState, jax.Array]:
    """A network's next action on one seat's observation ([9, 9, 26]), its carry [1, H] continued (the play
    server's agent; `benchmarks/.../play_rounds.py`'s cloned person). `allowed` (bool[6]): the action is
    chosen among these only, by the policy's probabilities."""
    hist = history if network.config.partner_history else None
    lstm, logits, _ = forward(network, params, lstm, obs[None, None], jnp.reshape(first, (1, 1)), hist)
    logits = logits[0, 0] if allowed is None else jnp.where(allowed, logits[0, 0], -jnp.inf)
    return lstm, select_action(key, logits, greedy)


def _ways_aside(state: oc.EnvState, seat: jax.Array, last: jax.Array) -> jax.Array:
    """bool[6]: the moves that take `seat` onto a free floor cell out of the partner's way: not the
    partner's cell, not the one it faces (where it is heading), not the one `seat` tried to enter with its
    `last` action; all six actions where there is none."""
    vec = jnp.asarray(DIR_VEC)
    pos, partner = state.agent_pos[seat], state.agent_pos[1 - seat]
    cells = jnp.clip(pos + vec, 0, GRID_SIZE - 1)
    ahead = partner + vec[state.agent_dir[1 - seat]]
    tried = jnp.arange(len(DIR_VEC)) == last
    free = (
        (state.level.grid[cells[:, 0], cells[:, 1]] == Tile.FLOOR)
        & jnp.any(cells != partner, axis=1)
        & jnp.any(cells != ahead, axis=1)
        & ~tried
    )
    moves = jnp.concatenate([free, jnp.zeros(NUM_ACTIONS - len(DIR_VEC), bool)])
    return jnp.where(jnp.any(free), moves, jnp.ones(NUM_ACTIONS, bool))


class Compiled:
    """The jitted `start` and `advance` of one network architecture (and action choice).

    `give_way_after` N > 0: after N steps in a row whose moves a collision cancelled, the agent's next
    action is a move onto a free floor cell, the one its policy prefers among them (Carroll et al. 2019's
    agents step aside at random when stuck); it then plays its policy again. 0: always the policy's action.
    """

    def __init__(self, config: NetworkConfig, greedy: bool, give_way_after: int = 0) -> None:
        self.network = ActorCritic(config, NUM_ACTIONS)
        self.greedy = greedy
        self.give_way_after = give_way_after
        self.start = jax.jit(self._start)
        self.advance = jax.jit(self._advance)

    def _start(
        self, params: Any, level: Level, key: jax.Array, agent_seat: jax.Array, env_params: oc.EnvParams
    ) -> tuple[oc.EnvState, Prepared]:
        k_reset, k_act = jax.random.split(key)
        obs, state = oc.reset(k_reset, level, env_params)
        lstm = self.network.initial_carry((1,))
        history = empty_history((1, 1), self.network.config.partner_history)
        lstm, action = act(
            self.network, params, lstm, obs[agent_seat], jnp.array(True), history, k_act, self.greedy
        )
        branches = _branches(state, action, agent_seat, env_params)
        return state, Prepared(branches, lstm, history, action, jnp.int32(0), jnp.array(False))

    def _advance(
        self,
        params: Any,
        prepared: Prepared,
        human_action: jax.Array,
        key: jax.Array,
        agent_seat: jax.Array,
        env_params: oc.EnvParams,
    ) -> tuple[oc.StepOutput, Prepared]:
        out: oc.StepOutput = jax.tree.map(lambda x: x[human_action], prepared.branches)
        history = push_history(prepared.history, jnp.reshape(human_action, (1, 1)))
        bumps = jnp.where(out.collision, prepared.bumps + 1, 0).astype(jnp.int32)
        allowed, gives_way = None, jnp.array(False)
        if self.give_way_after > 0:
            aside = _ways_aside(out.state, agent_seat, prepared.agent_action)
            gives_way = (bumps >= self.give_way_after) & ~jnp.all(aside)
            allowed = jnp.where(gives_way, aside, jnp.ones(NUM_ACTIONS, bool))
        lstm, action = act(
            self.network,
            params,
            prepared.lstm,
            out.obs[agent_seat],
            jnp.array(False),
            history,
            key,
            self.greedy,
            allowed,
        )
        branches = _branches(out.state, action, agent_seat, env_params)
        return out, Prepared(branches, lstm, history, action, bumps, gives_way)


@cache
def compiled(config: NetworkConfig, greedy: bool, give_way_after: int = 0) -> Compiled:
    """One `Compiled` per (architecture, action choice, giving way) for the life of the process."""
    return Compiled(config, greedy, give_way_after)


# ---------------------------------------------------------------------------------------------------------
# COMPACT STATES
# ---------------------------------------------------------------------------------------------------------


def pot_cells(level: Level) -> np.ndarray:
    """int[P, 2] the (row, col) of every pot of the kitchen."""
    return np.argwhere(np.asarray(level.grid) == Tile.POT)


def compact_state(state: Any, pots: np.ndarray, index: int | None = None) -> dict[str, Any]:
    """The compact JSON of a host (NumPy) `EnvState`, or of its `index`-th entry when batched."""

    def leaf(x: Any) -> np.ndarray:
        a = np.asarray(x)
        return a if index is None else a[index]

    items = leaf(state.items)
    pot = leaf(state.pot)
    return {
        "t": int(leaf(state.time)),
        "pos": leaf(state.agent_pos).astype(int).tolist(),
        "dir": leaf(state.agent_dir).astype(int).tolist(),
        "inv": leaf(state.agent_inv).astype(int).tolist(),
        "items": [[int(r), int(c), int(items[r, c])] for r, c in np.argwhere(items != 0)],
        "pots": [[int(r), int(c), int(pot[r, c])] for r, c in pots],
    }


def expand_state(compact: dict[str, Any], level: Level) -> oc.EnvState:
    """The host (NumPy) `EnvState` a compact state describes on `level`: the inverse of `compact_state`
    (`episode` 0). `ValueError` naming the field if the compact state does not fit the kitchen."""
    try:
        pos = np.asarray(compact["pos"], np.int32)
        direction = np.asarray(compact["dir"], np.int32)
        inv = np.asarray(compact["inv"], np.int32)
        t = int(compact["t"])
        items_list, pots_list = list(compact["items"]), list(compact["pots"])
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"not a compact state ({type(err).__name__}: {err})") from err
    n = GRID_SIZE
    if pos.shape != (2, 2) or not ((pos >= 0) & (pos < n)).all():
        raise ValueError(f"pos {compact['pos']!r} is not two (row, col) cells of the {n}x{n} frame")
    if direction.shape != (2,) or not ((direction >= 0) & (direction < len(Direction))).all():
        raise ValueError(f"dir {compact['dir']!r} is not two facings (0..{len(Direction) - 1})")
    if inv.shape != (2,) or not ((inv >= 0) & (inv < len(Item))).all():
        raise ValueError(f"inv {compact['inv']!r} is not two held items (0..{len(Item) - 1})")
    if t < 0:
        raise ValueError(f"t {t} is negative")
    items = np.zeros((n, n), np.uint8)
    for entry in items_list:
        r, c, item = _triple("item", entry)
        if not (0 <= r < n and 0 <= c < n and 0 < item < len(Item)):
            raise ValueError(f"item {entry!r} is not [row, col, item 1..{len(Item) - 1}] in the frame")
        items[r, c] = item
    pot = np.zeros((n, n), np.uint8)
    cells = {(int(r), int(c)) for r, c in pot_cells(level)}
    seen = set()
    for entry in pots_list:
        r, c, status = _triple("pot", entry)
        if (r, c) not in cells or not 0 <= status <= oc.POT_EMPTY:
            raise ValueError(f"pot {entry!r} is not [row, col, status 0..{oc.POT_EMPTY}] of a pot cell")
        pot[r, c] = status
        seen.add((r, c))
    if seen != cells:
        raise ValueError(f"pots {sorted(seen)} are not the kitchen's pot cells {sorted(cells)}")
    host_level: Level = jax.tree.map(np.asarray, level)
    host: dict[str, Any] = {  # NumPy leaves, as `jax.device_get` gives an env state
        "agent_pos": pos,
        "agent_dir": direction,
        "agent_inv": inv,
        "items": items,
        "pot": pot,
        "time": np.int32(t),
        "episode": np.int32(0),
    }
    return oc.EnvState(level=host_level, **host)


def _triple(kind: str, entry: Any) -> tuple[int, int, int]:
    if not isinstance(entry, list) or len(entry) != 3 or not all(isinstance(v, int) for v in entry):
        raise ValueError(f"{kind} {entry!r} is not three integers [row, col, code]")
    return entry[0], entry[1], entry[2]


# ---------------------------------------------------------------------------------------------------------
# ROUNDS
# ---------------------------------------------------------------------------------------------------------


class StepResult(NamedTuple):
    """One committed step, on the host.

    Attributes:
        t: steps played in the round after this one (1-based index of the step).
        actions: [seat 0's, seat 1's] actions.
        reward: team sparse reward of the step.
        shaped: per-seat shaped rewards (unscaled).
        collision: a move was cancelled because both agents wanted the same cell or to swap.
        agent_gave_way: the agent's action was a step aside by the give-way rule, not its policy's own.
        done: the round ended with this step.
        state: compact state after the step.
        branches: the compact states the human's six next actions lead to (None once done).
        compute_s: server time of the step (jitted call and transfer).
    """

    t: int
    actions: list[int]
    reward: float
    shaped: list[float]
    collision: bool
    agent_gave_way: bool
    done: bool
    state: dict[str, Any]
    branches: list[dict[str, Any]] | None
    compute_s: float


@dataclass(frozen=True)
class RoundSetup:
    """Everything that fixes a round before it starts (recorded in its `round_start` event)."""

    policy: Policy
    level_name: str
    level: Level
    human_seat: int
    steps: int
    mode: str
    seed: int


class Round:
    """One round in progress: the device state between steps, and running totals.

    Not thread-safe; the session holding it calls `start` once and then `step` one call at a time.
    """

    def __init__(self, setup: RoundSetup, study: StudyConfig) -> None:
        self.setup = setup
        self.env_params = dataclasses.replace(study.env, max_steps=setup.steps)
        self.greedy = study.agent_actions == "greedy"
        self.fns = compiled(setup.policy.network, self.greedy, study.agent_gives_way_after)
        self.agent_seat = jnp.int32(1 - setup.human_seat)
        self.key = jax.random.PRNGKey(setup.seed)
        self.pots = pot_cells(setup.level)
        self.prepared: Prepared | None = None
        self.t = 0
        self.done = False
        self.team_return = 0.0
        self.shaped_return = 0.0
        self.collisions = 0

    def _next_key(self) -> jax.Array:
        self.key, sub = jax.random.split(self.key)
        return sub

    def start(self) -> tuple[dict[str, Any], list[dict[str, Any]]]:
        """Resets the env; returns (compact start state, the six next-state branches)."""
        state, self.prepared = self.fns.start(
            self.setup.policy.params, self.setup.level, self._next_key(), self.agent_seat, self.env_params
        )
        host_state, host_branches = jax.device_get((state, self.prepared.branches.state))
        return compact_state(host_state, self.pots), self._branch_states(host_branches)

    def _branch_states(self, branches: Any) -> list[dict[str, Any]]:
        return [compact_state(branches, self.pots, a) for a in range(NUM_ACTIONS)]

    def step(self, human_action: int, *, with_branches: bool) -> StepResult:
        """Plays the human's action (0..5) with the agent's prepared one; prepares the next step."""
        if self.prepared is None or self.done:
            raise RuntimeError("the round has not started or is over")
        if not 0 <= human_action < NUM_ACTIONS:
            raise ValueError(f"action must be an integer in [0, {NUM_ACTIONS - 1}], got {human_action}")
        t0 = time.perf_counter()
        agent_action, gave_way = self.prepared.agent_action, self.prepared.gives_way
        out, self.prepared = self.fns.advance(
            self.setup.policy.params,
            self.prepared,
            jnp.int32(human_action),
            self._next_key(),
            self.agent_seat,
            self.env_params,
        )
        fetch: tuple[Any, ...] = (
            out.state,
            out.reward,
            out.shaped_reward,
            out.collision,
            out.done,
            agent_action,
            gave_way,
        )
        if with_branches:
            fetch = (*fetch, self.prepared.branches.state)
        host = jax.device_get(fetch)
        state, reward, shaped, collision, done, agent, agent_gave_way = host[:7]
        self.t += 1
        self.done = bool(done)
        self.team_return += float(reward)
        self.shaped_return += float(np.sum(shaped))
        self.collisions += int(bool(collision))
        actions = [0, 0]
        actions[self.setup.human_seat] = human_action
        actions[1 - self.setup.human_seat] = int(agent)
        branches = self._branch_states(host[7]) if with_branches and not self.done else None
        return StepResult(
            self.t,
            actions,
            float(reward),
            [float(s) for s in np.asarray(shaped)],
            bool(collision),
            bool(agent_gave_way),
            self.done,
            compact_state(state, self.pots),
            branches,
            time.perf_counter() - t0,
        )


def warm_up(pools: list[PartnerPool], study: StudyConfig) -> float:
    """Compiles every architecture's `start`/`advance` (one short dummy round each); returns seconds."""
    t0 = time.perf_counter()
    seen: set[NetworkConfig] = set()
    for pool in pools:
        for policy in pool.policies:
            if policy.network in seen:
                continue
            seen.add(policy.network)
            setup = RoundSetup(policy, "cramped_room", classic_level("cramped_room"), 0, 2, study.mode, 0)
            r = Round(setup, study)
            r.start()
            r.step(STAY, with_branches=True)
    return time.perf_counter() - t0


__all__ = [
    "Compiled",
    "PartnerPool",
    "Round",
    "RoundSetup",
    "StepResult",
    "compact_state",
    "compiled",
    "expand_state",
    "level_json",
    "load_partner",
    "warm_up",
]
