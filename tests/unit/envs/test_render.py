"""Rendering: frame shapes, frames reacting to state changes, ASCII view, PNG/GIF files."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

from cec.envs import overcooked as oc
from cec.envs.overcooked import Action
from cec.envs.overcooked.render import (
    render_episode_gif,
    render_frame,
    render_level,
    rollout_frames,
    save_gif,
    save_png,
    state_to_ascii,
)
from cec.levels import Direction, Item, Level, Tile, to_ascii

KEY = jax.random.PRNGKey(0)
PARAMS = oc.EnvParams(random_start_facing=False)
CLASSIC = oc.classic_levels()
TS = 32


def start(level: Level) -> oc.EnvState:
    return oc.reset(KEY, level, PARAMS)[1]


def act(state: oc.EnvState, a0: int, a1: int = Action.STAY) -> oc.EnvState:
    return oc.step(KEY, state, jnp.asarray([a0, a1], jnp.int32), PARAMS).state


def with_pots(state: oc.EnvState, status: int) -> oc.EnvState:
    grid = np.asarray(state.level.grid)
    return state.replace(pot=jnp.asarray(np.where(grid == Tile.POT, status, 0), jnp.uint8))


def with_items(state: oc.EnvState, items: dict[tuple[int, int], int]) -> oc.EnvState:
    grid = np.zeros((9, 9), np.uint8)
    for (r, c), it in items.items():
        grid[r, c] = it
    return state.replace(items=jnp.asarray(grid))


def cell(frame: np.ndarray, r: int, c: int, ts: int = TS) -> np.ndarray:
    return frame[r * ts : (r + 1) * ts, c * ts : (c + 1) * ts]


# --- frames -------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(CLASSIC))
def test_frame_shape_and_dtype(name: str) -> None:
    level = CLASSIC[name]
    h, w = (int(v) for v in np.asarray(level.size))
    frame = render_level(level)
    assert frame.shape == (h * TS, w * TS, 3)
    assert frame.dtype == np.uint8
    np.testing.assert_array_equal(render_frame(start(level)), frame)


def test_cramped_room_size_and_tile_size() -> None:
    level = CLASSIC["cramped_room"]
    assert render_level(level).shape == (4 * 32, 5 * 32, 3)
    assert render_level(level, tile_size=16).shape == (4 * 16, 5 * 16, 3)
    with pytest.raises(ValueError, match="tile_size"):
        render_level(level, tile_size=2)


def test_render_is_deterministic() -> None:
    state = start(CLASSIC["coord_ring"])
    np.testing.assert_array_equal(render_frame(state), render_frame(state))


def test_frame_changes_when_agent_moves() -> None:
    state = start(CLASSIC["cramped_room"])  # seat 0 at (1, 1)
    moved = act(state, Action.DOWN)
    assert np.asarray(moved.agent_pos)[0].tolist() == [2, 1]
    before, after = render_frame(state), render_frame(moved)
    assert not np.array_equal(before, after)
    assert not np.array_equal(cell(before, 1, 1), cell(after, 1, 1))
    assert not np.array_equal(cell(before, 2, 1), cell(after, 2, 1))


def test_frame_changes_when_agent_turns() -> None:
    state = start(CLASSIC["cramped_room"])
    base = render_frame(state)
    for d in (Direction.SOUTH, Direction.EAST, Direction.WEST):
        turned = state.replace(agent_dir=jnp.asarray([d, Direction.NORTH], jnp.int32))
        assert not np.array_equal(render_frame(turned), base), d


def test_frame_changes_when_agent_picks_up() -> None:
    state = act(start(CLASSIC["cramped_room"]), Action.LEFT)  # seat 0 turns to the onion pile at (1, 0)
    picked = act(state, Action.INTERACT)
    assert int(picked.agent_inv[0]) == Item.ONION
    before, after = render_frame(state), render_frame(picked)
    assert not np.array_equal(cell(before, 1, 1), cell(after, 1, 1))
    # the two held items look different from each other
    plate = picked.replace(agent_inv=jnp.asarray([Item.PLATE, Item.NONE], jnp.int32))
    dish = picked.replace(agent_inv=jnp.asarray([Item.DISH, Item.NONE], jnp.int32))
    frames = [render_frame(s) for s in (picked, plate, dish)]
    for i in range(3):
        for j in range(i):
            assert not np.array_equal(frames[i], frames[j])


def test_seats_look_different() -> None:
    state = start(CLASSIC["cramped_room"])  # seats at (1, 1) and (1, 3), both facing north
    frame = render_frame(state)
    assert not np.array_equal(cell(frame, 1, 1), cell(frame, 1, 3))


def test_pot_states_render_differently() -> None:
    state = start(CLASSIC["cramped_room"])  # pot at (0, 2)
    statuses = [oc.POT_EMPTY, 22, 21, 15, 5, oc.POT_READY]
    pots = [cell(render_frame(with_pots(state, s)), 0, 2) for s in statuses]
    for i in range(len(pots)):
        for j in range(i):
            assert not np.array_equal(pots[i], pots[j]), (statuses[i], statuses[j])


def test_loose_items_render_on_counters() -> None:
    state = start(CLASSIC["cramped_room"])  # (2, 0) is a bare counter
    frames = [
        cell(render_frame(with_items(state, {(2, 0): it})), 2, 0)
        for it in (Item.NONE, Item.ONION, Item.PLATE, Item.DISH)
    ]
    for i in range(len(frames)):
        for j in range(i):
            assert not np.array_equal(frames[i], frames[j])


def test_batched_state_is_rejected() -> None:
    state = start(CLASSIC["cramped_room"])
    batch = jax.tree.map(lambda x: jnp.stack([x, x]), state)
    with pytest.raises(ValueError, match="unbatched"):
        render_frame(batch)
    with pytest.raises(ValueError, match="unbatched"):
        state_to_ascii(batch)


# --- ASCII --------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(CLASSIC))
def test_ascii_tiles_match_level_codec(name: str) -> None:
    level = CLASSIC[name]
    h = int(np.asarray(level.size)[0])
    text = state_to_ascii(start(level))
    assert text.split("\n")[:h] == to_ascii(level).split("\n")[:h]


def test_ascii_status_lines() -> None:
    state = with_items(start(CLASSIC["cramped_room"]), {(2, 0): Item.ONION, (2, 4): Item.DISH})
    state = state.replace(
        agent_dir=jnp.asarray([Direction.EAST, Direction.SOUTH], jnp.int32),
        agent_inv=jnp.asarray([Item.PLATE, Item.NONE], jnp.int32),
        time=jnp.asarray(7, jnp.int32),
    )
    lines = state_to_ascii(with_pots(state, 21)).split("\n")
    assert lines[:4] == ["WWPWW", "O0 1O", "o   d", "WBWXW"]
    text = "\n".join(lines[4:])
    assert "time: 7" in text
    assert "seat 0 (1,1): facing east, holding plate" in text
    assert "seat 1 (1,3): facing south, holding nothing" in text
    assert "pot (0,2): 2 onions" in text
    assert "pot (0,2): empty" in state_to_ascii(with_pots(state, oc.POT_EMPTY))
    assert "pot (0,2): 1 onion" in state_to_ascii(with_pots(state, 22))
    assert "pot (0,2): cooking, 7 steps left" in state_to_ascii(with_pots(state, 7))
    assert "pot (0,2): ready" in state_to_ascii(with_pots(state, oc.POT_READY))


# --- files --------------------------------------------------------------------------------------


def walk(level: Level, moves: list[int]) -> oc.EnvState:
    """A jitted scan of seat-0 moves (seat 1 stays); returns the reset state and every next one."""

    @jax.jit
    def run(first: oc.EnvState, acts: jax.Array) -> oc.EnvState:
        def body(s: oc.EnvState, a: jax.Array) -> tuple[oc.EnvState, oc.EnvState]:
            nxt = oc.step(KEY, s, jnp.stack([a, jnp.int32(Action.STAY)]), PARAMS).state
            return nxt, nxt

        _, rest = jax.lax.scan(body, first, acts)
        return jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), first, rest)

    return run(start(level), jnp.asarray(moves, jnp.int32))


def test_rollout_frames_and_gif(tmp_path: Path) -> None:
    level = CLASSIC["cramped_room"]
    states = walk(level, [Action.DOWN, Action.RIGHT, Action.UP, Action.LEFT])  # every step moves seat 0
    frames = rollout_frames(states)
    assert len(frames) == 5
    assert all(f.shape == (128, 160, 3) and f.dtype == np.uint8 for f in frames)
    np.testing.assert_array_equal(frames[0], render_level(level))
    np.testing.assert_array_equal(frames[2], render_frame(jax.tree.map(lambda x: x[2], states)))

    path = save_gif(frames, tmp_path / "sub" / "walk.gif", fps=10)
    assert path.exists()
    with Image.open(path) as gif:
        assert gif.n_frames == 5
        assert gif.size == (160, 128)
        assert gif.info.get("loop") == 0


def test_gif_merges_identical_frames_keeping_duration(tmp_path: Path) -> None:
    frame = render_level(CLASSIC["cramped_room"])
    path = save_gif([frame, frame, frame], tmp_path / "still.gif", fps=5)
    with Image.open(path) as gif:
        assert gif.n_frames == 1
        assert gif.info["duration"] == 600


def test_save_png_round_trips(tmp_path: Path) -> None:
    frame = render_level(CLASSIC["forced_coord"])
    path = save_png(frame, tmp_path / "a" / "b.png")
    with Image.open(path) as png:
        np.testing.assert_array_equal(np.asarray(png.convert("RGB")), frame)
    with pytest.raises(ValueError, match="uint8"):
        save_png(frame.astype(np.float32), tmp_path / "bad.png")
    with pytest.raises(ValueError, match="at least one frame"):
        save_gif([], tmp_path / "empty.gif")


@pytest.mark.parametrize("policy", ["random", "scripted"])
def test_render_episode_gif(policy: str, tmp_path: Path) -> None:
    steps = 10
    path = render_episode_gif(
        CLASSIC["cramped_room"], tmp_path / f"{policy}.gif", steps=steps, policy=policy, fps=10
    )
    with Image.open(path) as gif:
        assert gif.size == (160, 128)
        assert 1 <= gif.n_frames <= steps + 1
        total = 0
        for i in range(gif.n_frames):
            gif.seek(i)
            total += gif.info["duration"]
    assert total == (steps + 1) * 100  # identical frames merge, but every state keeps its time


def test_render_episode_gif_rejects_bad_arguments(tmp_path: Path) -> None:
    level = CLASSIC["cramped_room"]
    with pytest.raises(ValueError, match="unknown policy 'greedy'"):
        render_episode_gif(level, tmp_path / "x.gif", policy="greedy")
    with pytest.raises(ValueError, match="steps"):
        render_episode_gif(level, tmp_path / "x.gif", steps=0)
    assert not (tmp_path / "x.gif").exists()
