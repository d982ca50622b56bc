"""Cross-play as a library: any policies x any levels, both seat orders, N episodes, common random numbers.

    policies, skipped = load_policies(load_zoo("zoo.yaml"))
    table = crossplay(policies, eval_levels("overcooked", "heldout"), EvalConfig(episodes=4), skipped=skipped)
    write_csv(table, "results.csv")

How the work is laid out:

- A *game* is (policy in seat 0, policy in seat 1, the levels both accept). A pairing of two different
  policies is two games (both seat orders); self-play is one.
- Games that share their level set are played together: one jitted call vmaps the one `rollout`
  (`cec.training.rollout`, `per_seat=True`) over games (each game its own two parameter sets) and over
  envs (one env per level x episode), for exactly one episode of `max_steps` steps per env. With
  `games_per_call` = 0 every game of a level set is in one call; otherwise calls of that many games
  (the last one padded, so one compilation serves all).
- Common random numbers: the env (level x episode) draws every random number (its reset and every
  step's action sampling and env keys) from `fold_in(fold_in(PRNGKey(seed), crc32(level name)),
  episode)`. So every pairing, seat order, batch composition and run with the same `seed` meets the same
  randomness on the same level and episode, and pairings are compared on equal terms.

Size: who can join a line-up (compatibility, the network it is played through), which games it plays and
the one jitted call that plays them read the same `Game`s and line-up; split, each part would reach into
the other's private helpers.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import time
import zlib
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cec.agents.network import (
    ActorCritic,
    NetworkConfig,
    embed_frame,
    embed_partner_model,
    frame_embeddable,
    frame_size,
)
from cec.agents.policy import Policy
from cec.config import ConfigError
from cec.envs.registry import game
from cec.envs.task import Task
from cec.evaluation.results import ARRAY_FIELDS, EpisodeTable, SkippedEntry, make_table
from cec.training.rollout import init_carry, rollout

log = logging.getLogger("cec.evaluation")

PAIR_MODES = ("all", "self", "with:<name>")


@dataclass(frozen=True)
class EvalConfig:
    """What a cross-play evaluation plays.

    Attributes:
        levels: level set (see `eval_levels`): Overcooked `heldout` (5 classic + 100 generated),
            `classic`, `generated`, or comma-separated level names, ASCII kitchen files and folders of
            them (`cec.levels.named`); Dual Destination `fixed`,
            `multi_task`, `generated` (100 held-out generated tasks), `heldout` (fixed + generated) or
            level names.
        episodes: episodes per pairing, seat order and level.
        greedy: act with the most likely action instead of sampling.
        seed: base seed of the common random numbers.
        max_steps: episode length; 0: the training episode length of the first (network) policy.
        pairs: `all` (every pair of policies, self-play included), `self` (self-play only) or
            `with:<name>` (that policy with every policy, itself included).
        games_per_call: games per jitted call (0: all games sharing a level set in one call); bounds
            memory on large zoos.
    """

    levels: str = "heldout"
    episodes: int = 4
    greedy: bool = False
    seed: int = 0
    max_steps: int = 0
    pairs: str = "all"
    games_per_call: int = 0

    def __post_init__(self) -> None:
        if self.episodes < 1:
            raise ConfigError(f"episodes must be at least 1, got {self.episodes}")
        if self.max_steps < 0 or self.games_per_call < 0:
            raise ConfigError("max_steps and games_per_call must be >= 0 (0: the default)")
        if self.pairs not in ("all", "self") and not self.pairs.startswith("with:"):
            raise ConfigError(f"pairs {self.pairs!r} is unknown; choose one of {list(PAIR_MODES)}")


class EvalLevels(NamedTuple):
    """Named levels to evaluate on: `names[i]` is `levels[i]` (a batched level with leading axis L)."""

    names: tuple[str, ...]
    levels: Any


def eval_levels(env: str, spec: str) -> EvalLevels:
    """The levels named by `spec` for game `env` (see `EvalConfig.levels`), in a stable order."""
    g = game(env)
    named = g.named_levels(spec)
    return EvalLevels(tuple(named), g.stack_levels(list(named.values())))


class Game(NamedTuple):
    """One game: `a` (row policy) in seat `seat`, `b` in the other, on `levels` (indices into the set)."""

    a: int
    b: int
    seat: int
    levels: tuple[int, ...]


class EpisodeOutcome(NamedTuple):
    """Per-episode sums from one rollout (leading axes [games, envs])."""

    returns: jax.Array
    shaped: jax.Array
    collisions: jax.Array
    dones: jax.Array


def episode_key(seed: int, level_name: str, episode: int) -> jax.Array:
    """The key every random draw of (level, episode) comes from (common random numbers)."""
    return _episode_keys(seed, [level_name], [episode])[0]


def _episode_keys(seed: int, names: Sequence[str], episodes: Sequence[int]) -> jax.Array:
    hashes = jnp.asarray([zlib.crc32(n.encode()) for n in names], jnp.uint32)
    base = jax.random.PRNGKey(seed)
    return jax.vmap(lambda h, n: jax.random.fold_in(jax.random.fold_in(base, h), n))(
        hashes, jnp.asarray(list(episodes), jnp.uint32)
    )


# ---------------------------------------------------------------------------------------------------------
# COMPATIBILITY AND THE GAME PLAN
# ---------------------------------------------------------------------------------------------------------


def _obs_settings(policy: Policy) -> tuple:
    """The env settings the policy's observations depend on (they must agree for cross-play)."""
    return policy.env.game.obs_settings(policy.env.params)


def _architecture(network: NetworkConfig) -> NetworkConfig:
    """What must agree between networks that cross-play batches through one: all but E3T's partner model
    and an egocentric frame's reach, which zero weights widen (`_lineup`)."""
    radius = 0 if frame_embeddable(network) else network.egocentric_radius
    return dataclasses.replace(network, partner_history=0, egocentric_radius=radius)


def compatibility_problem(reference: Policy, policy: Policy, level_names: Sequence[str]) -> str | None:
    """Why `policy` cannot join an evaluation led by `reference` on `level_names`, or None.

    A scripted policy joins any evaluation of its game: it has no network, and it reads whatever the
    evaluation's observations show (e.g. `dd_oracle` adapts to the partial view and the pink goals).
    """
    if policy.env.name != reference.env.name:
        return f"it plays {policy.env.name}, the evaluation plays {reference.env.name}"
    networks = policy.scripted is None and reference.scripted is None
    if networks and _architecture(policy.network) != _architecture(reference.network):
        return (
            f"its network {policy.network} differs from the evaluation's {reference.network} (the first "
            "policy's); cross-play batches both seats through one architecture (E3T's partner model and "
            "an egocentric frame's reach aside): evaluate each architecture in its own run"
        )
    if networks and _obs_settings(policy) != _obs_settings(reference):
        return (
            f"it was trained with Dual Destination (partial_obs, multi_task) = {_obs_settings(policy)}, "
            f"the evaluation uses {_obs_settings(reference)} (its observations would differ)"
        )
    if policy.levels is not None and not set(policy.levels) & set(level_names):
        return f"none of its levels {list(policy.levels)} is in the evaluation's level set"
    return None


def plan_games(
    policies: Sequence[Policy],
    level_names: Sequence[str],
    pairs: str = "all",
    involving: Collection[str] | None = None,
) -> list[Game]:
    """The games to play: both seat orders of each pair of different policies, self-play once; with
    `involving`, only the games in which a policy of those names plays (the rest already played)."""
    names = [p.name for p in policies]
    if pairs == "all":
        combos = [(i, j) for i in range(len(policies)) for j in range(i, len(policies))]
    elif pairs == "self":
        combos = [(i, i) for i in range(len(policies))]
    elif pairs.startswith("with:"):
        who = pairs.removeprefix("with:")
        if who not in names:
            raise ConfigError(f"pairs={pairs!r}: no policy named {who!r} among {names}")
        k = names.index(who)
        combos = [(k, j) for j in range(len(policies))]
    else:
        raise ConfigError(f"pairs {pairs!r} is unknown; choose one of {list(PAIR_MODES)}")
    if involving is not None:
        combos = [(i, j) for i, j in combos if names[i] in involving or names[j] in involving]
    games = []
    for i, j in combos:
        allowed = [
            li
            for li, name in enumerate(level_names)
            if all(p.levels is None or name in p.levels for p in (policies[i], policies[j]))
        ]
        if not allowed:
            continue
        for seat in (0,) if i == j else (0, 1):
            games.append(Game(i, j, seat, tuple(allowed)))
    return games


# ---------------------------------------------------------------------------------------------------------
# THE JITTED CALL
# ---------------------------------------------------------------------------------------------------------


def _module(network: NetworkConfig, task: Task, scripted: tuple[str, ...]) -> Any:
    """The network both seats run: the policies' own, or with scripted kinds `WithScripted` around it."""
    if not scripted:
        return ActorCritic(network, task.num_actions)
    from cec.agents.scripted import WithScripted

    return WithScripted(network, task.num_actions, scripted=scripted)


def _one_episode(
    pair_params: Any, level: Any, key: jax.Array, env_params: Any, *, task: Task, net: Any, **rollout_kw: Any
) -> Any:
    """The `Trajectory` of one episode of the two seats' parameters (`per_seat`) on one level."""
    k_reset, k_play = jax.random.split(key)
    buffer = jax.tree.map(lambda x: x[None, None], level)  # E = 1 env, K = 1 level
    carry = init_carry(task, net, env_params, buffer, k_reset)
    _, traj = rollout(
        pair_params,
        carry,
        buffer,
        k_play,
        task=task,
        network=net,
        env_params=env_params,
        per_seat=True,
        **rollout_kw,
    )
    return traj


@functools.cache
def play_fn(
    task: Task, network: NetworkConfig, num_steps: int, greedy: bool, scripted: tuple[str, ...] = ()
) -> Callable[..., EpisodeOutcome]:
    """The compiled evaluation call (cached per game, network, episode length, action mode and scripted
    kinds).

    (pair_params: leaves [G, 2, ...], levels: [E, ...], keys: [E, 2], env_params) -> `EpisodeOutcome`
    with [G, E] leaves: every game plays one episode of `num_steps` steps on every env. With `scripted`
    kinds the network is `cec.agents.scripted.WithScripted` (parameters from `with_scripted_params`):
    each seat's parameter set says whether it plays the network or one of the kinds.
    """
    net = _module(network, task, scripted)

    def one_env(pair_params: Any, level: Any, key: jax.Array, env_params: Any) -> EpisodeOutcome:
        traj = _one_episode(
            pair_params, level, key, env_params, task=task, net=net, num_steps=num_steps, greedy=greedy
        )
        return EpisodeOutcome(
            traj.reward.sum(),
            traj.shaped.sum(),
            traj.collision.sum().astype(jnp.float32),
            traj.done.sum().astype(jnp.int32),
        )

    per_game = jax.vmap(one_env, in_axes=(None, 0, 0, None))
    return jax.jit(jax.vmap(per_game, in_axes=(0, None, None, None)))


@functools.cache
def _states_fn(
    task: Task, network: NetworkConfig, num_steps: int, greedy: bool, scripted: tuple[str, ...]
) -> Callable[..., Any]:
    net = _module(network, task, scripted)

    def run(pair_params: Any, level: Any, key: jax.Array, env_params: Any) -> tuple[Any, jax.Array]:
        traj = _one_episode(
            pair_params,
            level,
            key,
            env_params,
            task=task,
            net=net,
            num_steps=num_steps,
            greedy=greedy,
            record="state",
        )
        return jax.tree.map(lambda x: x[:, 0], traj.state), traj.reward[:, 0].sum()

    return jax.jit(run)


def _lineup(policies: Sequence[Policy], reference: Policy) -> tuple[Task, NetworkConfig, tuple[str, ...]]:
    """The game, the one network architecture and the scripted kinds an evaluation of `policies` runs.

    Networks that differ only in E3T's partner model and in their egocentric frame's reach play as one
    architecture: the longest history and the largest frame, the others embedded with zero weights
    (`embed_partner_model`, `embed_frame`: the same policies exactly)."""
    task = Task.from_config(reference.env)
    nets = [p.network for p in policies if p.scripted is None]
    k = max((n.partner_history for n in nets), default=0)
    largest = max(nets, key=lambda n: frame_size(n, _grid(task)), default=reference.network)
    network = dataclasses.replace(
        reference.network, partner_history=k, egocentric_radius=largest.egocentric_radius
    )
    kinds = tuple(sorted({p.scripted for p in policies if p.scripted is not None}))
    return task, network, kinds


def _grid(task: Task) -> tuple[int, int]:
    """The observation's grid (H, W): what an egocentric frame's reach is measured over."""
    return task.obs_shape[0], task.obs_shape[1]


def _embedded(policy: Policy, network: NetworkConfig, task: Task) -> Any:
    """A network policy's parameters in the evaluation's `network` (`_lineup`)."""
    params, own = policy.params, policy.network
    if own.egocentric_radius != network.egocentric_radius:
        params = embed_frame(params, own, network.egocentric_radius, _grid(task))
        own = dataclasses.replace(own, egocentric_radius=network.egocentric_radius)
    return embed_partner_model(params, own, network, task.num_actions)


def episode_states(
    seat0: Policy,
    seat1: Policy,
    level: Any,
    level_name: str,
    *,
    seed: int = 0,
    max_steps: int = 0,
    greedy: bool = False,
) -> tuple[Any, float]:
    """One episode of `seat0` and `seat1` on `level`, as `crossplay` plays episode 0 of that pairing and
    seat order (the same keys): the env states the actions were taken in (leading axis T, each with its
    level, ready for `cec.envs.overcooked.render.rollout_frames`) and the team return."""
    reference = next((p for p in (seat0, seat1) if p.scripted is None), seat0)
    for p in (seat0, seat1):
        problem = compatibility_problem(reference, p, [level_name])
        if problem is not None:
            raise ConfigError(f"{p.name} cannot play with {reference.name} on {level_name}: {problem}")
    task, network, kinds = _lineup([seat0, seat1], reference)
    steps = max_steps or int(reference.env.params.max_steps)
    env_params = task.game.evaluation_params(reference.env.params).replace(max_steps=steps)
    pair = _stack([_seat_params(p, network, task, kinds) for p in (seat0, seat1)])
    fn = _states_fn(task, network, steps, greedy, kinds)
    states, team_return = jax.device_get(fn(pair, level, episode_key(seed, level_name, 0), env_params))
    n = int(np.shape(states.agent_pos)[0])
    levels = jax.tree.map(lambda x: np.broadcast_to(np.asarray(x), (n, *np.shape(x))), level)
    return states.replace(level=levels), float(team_return)


def episode_sheet(
    seat0: Policy,
    seat1: Policy,
    level: Any,
    level_name: str,
    path: Path,
    *,
    every: int = 25,
    max_steps: int = 0,
) -> float:
    """Plays `episode_states` and saves every `every`-th frame of it as one picture at `path` (a PNG, eight
    frames a row); returns the team return."""
    from cec.envs.overcooked.render import contact_sheet, rollout_frames, save_png

    states, team_return = episode_states(seat0, seat1, level, level_name, max_steps=max_steps)
    save_png(contact_sheet(rollout_frames(states, tile_size=24)[::every], columns=8), path)
    return team_return


def _seat_params(policy: Policy, network: NetworkConfig, task: Task, kinds: tuple[str, ...]) -> Any:
    """The parameter set a policy brings to a seat of the evaluation's network (see `play_fn`); without
    `kinds` a scripted policy brings zeros (a call without its kind plays none of its games)."""
    from cec.agents.scripted import placeholder_params, with_scripted_params

    if not kinds:
        if policy.scripted is None:
            return _embedded(policy, network, task)
        return placeholder_params(ActorCritic(network, task.num_actions), task.obs_shape)

    if policy.scripted is None:
        return with_scripted_params(_embedded(policy, network, task), 0)
    zeros = placeholder_params(ActorCritic(network, task.num_actions), task.obs_shape)
    return with_scripted_params(zeros, kinds.index(policy.scripted) + 1)


def _stack(trees: Sequence[Any]) -> Any:
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trees)


def crossplay(
    policies: Sequence[Policy],
    levels: EvalLevels,
    config: EvalConfig = EvalConfig(),
    *,
    skipped: Sequence[SkippedEntry] = (),
    progress: Callable[[str], None] | None = None,
    involving: Collection[str] | None = None,
) -> EpisodeTable:
    """Plays the games of `config.pairs` among `policies` on `levels` (with `involving`, only those in
    which a policy of those names plays); returns the long result table.

    The first network policy leads (its network and env settings; a scripted one only when every policy
    is scripted). Policies that cannot join (another game, network or observation settings, or none of
    their levels in the set) are added to the table's skipped entries with the reason, like the `skipped`
    entries passed in (zoo entries that failed to load). Scripted policies (`cec.agents.scripted`)
    play in both seats, in jitted calls of the games with a scripted partner; the games of two networks
    play in calls without the scripted kinds (the same episodes, faster).
    """
    skipped_out = list(skipped)
    if not policies:
        reasons = "; ".join(f"{s.name}: {s.reason}" for s in skipped)
        raise ConfigError(
            "no policy to evaluate" + (f"; every zoo entry was skipped: {reasons}" if reasons else "")
        )
    # the first network policy leads (its network and env settings); scripted policies adapt to it
    reference = next((p for p in policies if p.scripted is None), policies[0])
    usable: list[Policy] = []
    for p in policies:
        problem = compatibility_problem(reference, p, levels.names)
        if problem is None:
            usable.append(p)
        else:
            skipped_out.append(SkippedEntry(p.name, p.algorithm, p.seed, problem))
    task, network, kinds = _lineup(usable, reference)
    env_params = task.game.evaluation_params(reference.env.params)
    steps = config.max_steps or int(env_params.max_steps)
    env_params = env_params.replace(max_steps=steps)
    games = plan_games(usable, levels.names, config.pairs, involving)
    rows: dict[str, list] = {k: [] for k in ARRAY_FIELDS if k not in _SET_BY_TABLE}
    # games of two networks play without the scripted kinds, whose rollout in every env of a call costs
    # about as much as the network's (with the cook in a line-up, half the episodes per second)
    scripted = {i for i, p in enumerate(usable) if p.scripted is not None}
    plain = [g for g in games if not scripted & {g.a, g.b}]
    for subset, with_kinds in ((plain, ()), ([g for g in games if scripted & {g.a, g.b}], kinds)):
        if subset:
            seats = [_seat_params(p, network, task, with_kinds) for p in usable]
            fn = play_fn(task, network, steps, config.greedy, with_kinds)
            _play_games(subset, usable, _stack(seats), fn, levels, env_params, config, rows, progress)
    return _to_table(rows, reference, env_params, steps, config.greedy, skipped_out)


def _play_games(
    games: Sequence[Game],
    usable: Sequence[Policy],
    stacked: Any,
    fn: Callable[..., EpisodeOutcome],
    levels: EvalLevels,
    env_params: Any,
    config: EvalConfig,
    rows: dict[str, list],
    progress: Callable[[str], None] | None,
) -> None:
    """Plays `games` with the compiled call `fn` and the seats' parameters `stacked` (one per policy of
    `usable`), `config.games_per_call` at a time, appending their rows."""
    groups: dict[tuple[int, ...], list[Game]] = {}
    for g in games:
        groups.setdefault(g.levels, []).append(g)
    n = config.episodes
    for level_idx, group in groups.items():
        env_level = np.repeat(np.asarray(level_idx), n)  # env e plays level env_level[e], episode e % n
        env_episode = np.tile(np.arange(n), len(level_idx))
        lv = jax.tree.map(lambda x, rows=env_level: jnp.asarray(np.asarray(x)[rows]), levels.levels)
        keys = _episode_keys(config.seed, [levels.names[i] for i in env_level], env_episode.tolist())
        per_call = config.games_per_call or len(group)
        for start in range(0, len(group), per_call):
            chunk = group[start : start + per_call]
            padded = chunk + [chunk[-1]] * (per_call - len(chunk))
            seat0 = np.asarray([g.a if g.seat == 0 else g.b for g in padded])
            seat1 = np.asarray([g.b if g.seat == 0 else g.a for g in padded])
            pair_params = jax.tree.map(
                lambda x, s0=seat0, s1=seat1: np.stack([x[s0], x[s1]], axis=1), stacked
            )
            t0 = time.perf_counter()
            out = jax.device_get(fn(pair_params, lv, keys, env_params))
            if progress is not None:
                progress(
                    f"{len(chunk)} game(s) x {len(env_level)} episode(s) on {len(level_idx)} level(s) "
                    f"in {time.perf_counter() - t0:.1f}s"
                )
            if not np.all(out.dones[: len(chunk)] == 1):
                raise RuntimeError("an evaluation env did not finish exactly one episode; this is a bug")
            for gi, g in enumerate(chunk):
                _append_rows(
                    rows, usable[g.a], usable[g.b], g.seat, levels.names, env_level, env_episode, out, gi
                )


#: Result fields `_to_table` fills for the whole table (deliveries from the returns), not `_append_rows`.
_SET_BY_TABLE = ("deliveries", "env", "episode_steps", "actions")


def _append_rows(
    rows: dict[str, list],
    a: Policy,
    b: Policy,
    seat: int,
    names: Sequence[str],
    env_level: np.ndarray,
    env_episode: np.ndarray,
    out: EpisodeOutcome,
    gi: int,
) -> None:
    e = len(env_level)
    rows["policy_a"] += [a.name] * e
    rows["algorithm_a"] += [a.algorithm] * e
    rows["seed_a"] += [a.seed] * e
    rows["policy_b"] += [b.name] * e
    rows["algorithm_b"] += [b.algorithm] * e
    rows["seed_b"] += [b.seed] * e
    rows["level"] += [names[i] for i in env_level]
    rows["seat"] += [seat] * e
    rows["episode"] += env_episode.tolist()
    rows["returns"] += np.asarray(out.returns[gi], np.float64).tolist()
    rows["collisions"] += np.asarray(out.collisions[gi], np.float64).tolist()
    rows["shaped_return"] += np.asarray(out.shaped[gi], np.float64).tolist()


def _to_table(
    rows: dict[str, list],
    reference: Policy,
    env_params: Any,
    steps: int,
    greedy: bool,
    skipped: Sequence[SkippedEntry],
) -> EpisodeTable:
    returns = np.asarray(rows["returns"], np.float64)
    deliveries = reference.env.game.deliveries(returns, steps, env_params)
    n = len(returns)
    return make_table(
        {
            **rows,
            "deliveries": deliveries,
            "env": [reference.env.name] * n,
            "episode_steps": [steps] * n,
            "actions": ["greedy" if greedy else "sampled"] * n,
        },
        skipped,
    )
