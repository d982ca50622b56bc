"""Rendering of Overcooked states: RGB frames (NumPy + Pillow), terminal ASCII, PNG and GIF files.

Everything here runs on the host and draws one unbatched state at a time; states are pulled off
the device once per call. Frames are cropped to the kitchen's own size (`level.size`), so a 4x5
kitchen at `tile_size=32` gives a `(128, 160, 3)` uint8 image. Drawing is deterministic: the same
state and tile size always give the same pixels.

    render_frame(state)        one state -> RGB frame
    render_level(level)        a level's start state -> RGB frame
    state_to_ascii(state)      one state -> text (tiles, agents, loose items, then a status block)
    rollout_frames(states)     a time-stacked state (leading axis T, as `lax.scan` stacks) -> frames
    save_png / save_gif        write frames to disk
    render_episode_gif(level)  roll out one episode (random or scripted policy), save it as a GIF

Size: sprite drawing for every tile, object and agent state; one table of pictures, no logic to split.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from PIL import Image, ImageDraw

from cec.envs.overcooked.dynamics import reset, step
from cec.envs.overcooked.scripted import scripted_actions
from cec.envs.overcooked.state import (
    MAX_ONIONS,
    NUM_ACTIONS,
    POT_EMPTY,
    POT_FULL,
    POT_READY,
    EnvParams,
    EnvState,
)
from cec.levels import DIR_VEC, Direction, Item, Level, Tile, validate_level
from cec.levels.ascii import CHAR_OF_TILE

__all__ = [
    "POLICIES",
    "contact_sheet",
    "render_episode_gif",
    "render_frame",
    "render_level",
    "rollout_frames",
    "save_gif",
    "save_png",
    "side_by_side",
    "state_to_ascii",
]

#: Policy names accepted by `render_episode_gif`.
POLICIES = ("random", "scripted")
SCRIPTED_EPSILON = 0.1
MIN_TILE_SIZE = 8
_SUPERSAMPLE = 2  # draw at this multiple of the tile size, then downsample (smooth edges)

RGB = tuple[int, int, int]
BACKGROUND: RGB = (255, 255, 255)  # between panels of a side-by-side GIF
_FLOOR: RGB = (238, 232, 218)
_FLOOR_LINE: RGB = (220, 212, 194)
_COUNTER: RGB = (168, 128, 88)
_COUNTER_EDGE: RGB = (116, 84, 54)
_ONION: RGB = (242, 200, 44)
_ONION_EDGE: RGB = (160, 112, 16)
_PLATE: RGB = (252, 252, 252)
_PLATE_EDGE: RGB = (128, 128, 128)
_SOUP: RGB = (236, 118, 28)
_SOUP_EDGE: RGB = (170, 74, 12)
_POT: RGB = (52, 52, 58)
_POT_RIM: RGB = (112, 112, 122)
_BAR_BG: RGB = (40, 28, 20)
_READY: RGB = (60, 220, 90)
_GOAL: RGB = (62, 160, 72)
_GOAL_INNER: RGB = (138, 212, 138)
_AGENT: tuple[RGB, RGB] = ((52, 104, 224), (214, 58, 48))  # seat 0 blue, seat 1 red
_AGENT_DARK: tuple[RGB, RGB] = ((22, 48, 128), (120, 24, 18))
_WHITE: RGB = (255, 255, 255)

_ITEM_NAMES = {Item.NONE: "nothing", Item.ONION: "onion", Item.PLATE: "plate", Item.DISH: "dish"}
_ITEM_CHARS = {Item.ONION: "o", Item.PLATE: "b", Item.DISH: "d"}


# --------------------------------------------------------------------------------------------------
# Host-side state access
# --------------------------------------------------------------------------------------------------


def _host(state: EnvState, what: str) -> EnvState:
    """The state with NumPy leaves, checked to be a single (unbatched) state."""
    host: EnvState = jax.device_get(state)
    if np.ndim(host.agent_pos) != 2 or np.ndim(host.level.grid) != 2:
        raise ValueError(
            f"{what} takes one unbatched EnvState (agent_pos of shape (2, 2)), got agent_pos of "
            f"shape {np.shape(host.agent_pos)}; index the batch first, e.g. "
            "jax.tree.map(lambda x: x[i], states), or use rollout_frames for a time-stacked state"
        )
    return host


def _check_tile_size(tile_size: int) -> None:
    if not isinstance(tile_size, int | np.integer) or tile_size < MIN_TILE_SIZE:
        raise ValueError(f"tile_size must be an integer >= {MIN_TILE_SIZE} pixels, got {tile_size!r}")


def _kitchen_shape(host: EnvState) -> tuple[int, int]:
    h, w = (int(v) for v in np.asarray(host.level.size))
    return h, w


def _onions_in_pot(status: int) -> int:
    return int(np.clip(POT_EMPTY - status, 0, MAX_ONIONS))


def _pot_text(status: int) -> str:
    if status == POT_READY:
        return "ready"
    if status <= POT_FULL:
        return f"cooking, {status} steps left"
    n = _onions_in_pot(status)
    return "empty" if n == 0 else f"{n} onion" + ("s" if n > 1 else "")


# --------------------------------------------------------------------------------------------------
# Drawing
# --------------------------------------------------------------------------------------------------


class _Canvas:
    """A Pillow drawing surface with helpers in cell-relative coordinates (0..1 within a cell)."""

    def __init__(self, height: int, width: int, cell: int) -> None:
        self.cell = cell
        self.image = Image.new("RGB", (width * cell, height * cell), _FLOOR)
        self.draw = ImageDraw.Draw(self.image)
        self.line = max(1, round(cell / 24))

    def xy(self, r: int, c: int, fy: float, fx: float) -> tuple[float, float]:
        return (c + fx) * self.cell, (r + fy) * self.cell

    def rect(
        self,
        r: int,
        c: int,
        box: tuple[float, float, float, float],
        fill: RGB,
        outline: RGB | None = None,
        radius: float = 0.0,
        width: int | None = None,
    ) -> None:
        """Rectangle from (top, left) to (bottom, right), as cell fractions."""
        x0, y0 = self.xy(r, c, box[0], box[1])
        x1, y1 = self.xy(r, c, box[2], box[3])
        self.draw.rounded_rectangle(
            (x0, y0, x1 - 1, y1 - 1),
            radius=radius * self.cell,
            fill=fill,
            outline=outline,
            width=self.line if width is None else width,
        )

    def disc(
        self,
        r: int,
        c: int,
        fy: float,
        fx: float,
        rad: float,
        fill: RGB,
        outline: RGB | None = None,
    ) -> None:
        x, y = self.xy(r, c, fy, fx)
        d = rad * self.cell
        self.draw.ellipse((x - d, y - d, x + d, y + d), fill=fill, outline=outline, width=self.line)

    def polygon(self, r: int, c: int, points: Sequence[tuple[float, float]], fill: RGB) -> None:
        """Polygon through (fy, fx) cell-fraction points."""
        self.draw.polygon([self.xy(r, c, fy, fx) for fy, fx in points], fill=fill)

    def result(self, tile_size: int) -> np.ndarray:
        h, w = self.image.height // self.cell, self.image.width // self.cell
        small = self.image.resize((w * tile_size, h * tile_size), Image.Resampling.LANCZOS)
        return np.asarray(small, dtype=np.uint8).copy()


def _draw_item(cv: _Canvas, r: int, c: int, fy: float, fx: float, scale: float, item: int) -> None:
    """An item centred at (fy, fx) in cell (r, c); `scale` 1.0 is the counter-top size."""
    if item == Item.ONION:
        cv.disc(r, c, fy, fx, 0.2 * scale, _ONION, _ONION_EDGE)
    elif item in (Item.PLATE, Item.DISH):
        cv.disc(r, c, fy, fx, 0.27 * scale, _PLATE, _PLATE_EDGE)
        if item == Item.DISH:
            cv.disc(r, c, fy, fx, 0.17 * scale, _SOUP, _SOUP_EDGE)


def _draw_counter(cv: _Canvas, r: int, c: int) -> None:
    cv.rect(r, c, (0.0, 0.0, 1.0, 1.0), _COUNTER, _COUNTER_EDGE, width=cv.line)


def _draw_tile(cv: _Canvas, r: int, c: int, tile: int) -> None:
    if tile == Tile.FLOOR:
        cv.rect(r, c, (0.0, 0.0, 1.0, 1.0), _FLOOR, _FLOOR_LINE, width=max(1, cv.line // 2))
        return
    if tile == Tile.GOAL:
        cv.rect(r, c, (0.0, 0.0, 1.0, 1.0), _GOAL, _COUNTER_EDGE)
        cv.rect(r, c, (0.16, 0.16, 0.84, 0.84), _GOAL_INNER, _GOAL, radius=0.08, width=2 * cv.line)
        cv.disc(r, c, 0.5, 0.5, 0.18, _GOAL_INNER, _WHITE)  # an empty-dish mark: "deliver here"
        return
    _draw_counter(cv, r, c)
    if tile == Tile.ONION_PILE:
        for fy, fx in ((0.36, 0.32), (0.36, 0.68), (0.66, 0.5), (0.66, 0.2), (0.66, 0.8)):
            cv.disc(r, c, fy, fx, 0.15, _ONION, _ONION_EDGE)
    elif tile == Tile.PLATE_PILE:
        for k in range(3):
            cv.disc(r, c, 0.62 - 0.08 * k, 0.5, 0.3, _PLATE, _PLATE_EDGE)


def _draw_pot(cv: _Canvas, r: int, c: int, status: int) -> None:
    ready = status == POT_READY
    cooking = POT_READY < status <= POT_FULL
    if ready:  # a bright ring around the whole cell
        cv.rect(r, c, (0.03, 0.03, 0.97, 0.97), _COUNTER, _READY, width=3 * cv.line)
    # handles, body and rim
    cv.rect(r, c, (0.34, 0.06, 0.46, 0.94), _POT, radius=0.05)
    cv.rect(r, c, (0.2, 0.14, 0.8, 0.86), _POT, _POT_RIM, radius=0.1)
    if ready:
        cv.rect(r, c, (0.27, 0.22, 0.52, 0.78), _SOUP, _SOUP_EDGE, radius=0.08)
    else:
        for k in range(_onions_in_pot(status)):
            cv.disc(r, c, 0.38, 0.29 + 0.21 * k, 0.085, _ONION, _ONION_EDGE)
    if cooking or ready:  # progress bar along the bottom of the cell
        done = 1.0 if ready else (POT_FULL - status) / POT_FULL
        cv.rect(r, c, (0.84, 0.1, 0.95, 0.9), _BAR_BG)
        if done > 0:
            cv.rect(r, c, (0.84, 0.1, 0.95, 0.1 + 0.8 * done), _READY if ready else _SOUP)


def _draw_agent(cv: _Canvas, r: int, c: int, seat: int, facing: int, held: int) -> None:
    dr, dc = (float(v) for v in DIR_VEC[int(facing) % 4])
    pr, pc = -dc, dr  # perpendicular to the facing

    def at(along: float, across: float) -> tuple[float, float]:
        return 0.5 + along * dr + across * pr, 0.5 + along * dc + across * pc

    # a nose (triangle) pointing where the agent faces, then the body over its base
    cv.polygon(r, c, [at(0.47, 0.0), at(0.12, 0.24), at(0.12, -0.24)], _AGENT_DARK[seat])
    cv.disc(r, c, 0.5, 0.5, 0.32, _AGENT[seat], _AGENT_DARK[seat])
    # two eyes on the facing side
    for side in (0.12, -0.12):
        fy, fx = at(0.17, side)
        cv.disc(r, c, fy, fx, 0.055, _WHITE)
    if held != Item.NONE:
        fy, fx = at(-0.07, 0.0)
        _draw_item(cv, r, c, fy, fx, 0.62, held)


def _draw_state(host: EnvState, tile_size: int) -> np.ndarray:
    h, w = _kitchen_shape(host)
    grid = np.asarray(host.level.grid)
    items = np.asarray(host.items)
    pot = np.asarray(host.pot)
    cv = _Canvas(h, w, tile_size * _SUPERSAMPLE)
    for r in range(h):
        for c in range(w):
            tile = int(grid[r, c])
            if tile == Tile.POT:
                _draw_counter(cv, r, c)
                _draw_pot(cv, r, c, int(pot[r, c]))
            else:
                _draw_tile(cv, r, c, tile)
            if items[r, c] != Item.NONE:
                _draw_item(cv, r, c, 0.5, 0.5, 1.0, int(items[r, c]))
    pos = np.asarray(host.agent_pos)
    dirs = np.asarray(host.agent_dir)
    inv = np.asarray(host.agent_inv)
    for seat in range(pos.shape[0]):
        _draw_agent(cv, int(pos[seat, 0]), int(pos[seat, 1]), seat, int(dirs[seat]), int(inv[seat]))
    return cv.result(tile_size)


# --------------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------------


def render_frame(state: EnvState, tile_size: int = 32) -> np.ndarray:
    """Draws one unbatched state as an RGB image.

    Args:
        state: a single `EnvState` (not batched; see `rollout_frames` for time-stacked states).
        tile_size: pixels per cell side (at least `MIN_TILE_SIZE`).

    Returns:
        uint8[H * tile_size, W * tile_size, 3] where (H, W) = `state.level.size`: the kitchen only,
        without the frame's counter padding.
    """
    _check_tile_size(tile_size)
    return _draw_state(_host(state, "render_frame"), tile_size)


def render_level(level: Level, tile_size: int = 32) -> np.ndarray:
    """Draws a level's start state: agents at their start cells and facings, empty pots, hands."""
    if np.ndim(level.grid) != 2:
        raise ValueError(f"render_level takes one unbatched Level, got grid of shape {np.shape(level.grid)}")
    _, state = reset(jax.random.PRNGKey(0), level, EnvParams(random_start_facing=False))
    return render_frame(state, tile_size)


def state_to_ascii(state: EnvState) -> str:
    """A terminal view of one state.

    The first H lines are the kitchen with the codec's tile characters (`W O B P X` and space),
    agents as `0`/`1`, and loose items as `o` (onion), `b` (plate), `d` (dish). Then one line with
    the time, one per seat (cell, facing, held item) and one per pot (in reading order).
    """
    host = _host(state, "state_to_ascii")
    h, w = _kitchen_shape(host)
    grid = np.asarray(host.level.grid)
    items = np.asarray(host.items)
    pot = np.asarray(host.pot)
    rows = [[CHAR_OF_TILE[Tile(int(grid[r, c]))] for c in range(w)] for r in range(h)]
    for r in range(h):
        for c in range(w):
            item = int(items[r, c])
            if item != Item.NONE:
                rows[r][c] = _ITEM_CHARS.get(Item(item), "?")
    pos = np.asarray(host.agent_pos).tolist()
    for seat, (r, c) in enumerate(pos):
        if 0 <= r < h and 0 <= c < w:
            rows[r][c] = str(seat)
    lines = ["".join(row) for row in rows]
    lines.append(f"time: {int(host.time)}")
    dirs = np.asarray(host.agent_dir).tolist()
    inv = np.asarray(host.agent_inv).tolist()
    for seat, (r, c) in enumerate(pos):
        facing = Direction(int(dirs[seat])).name.lower()
        held = _ITEM_NAMES.get(Item(int(inv[seat])), str(inv[seat]))
        lines.append(f"seat {seat} ({r},{c}): facing {facing}, holding {held}")
    for r, c in zip(*np.nonzero(grid[:h, :w] == Tile.POT), strict=True):
        lines.append(f"pot ({r},{c}): {_pot_text(int(pot[r, c]))}")
    return "\n".join(lines)


def _check_fps(fps: int) -> None:
    if not isinstance(fps, int | np.integer) or fps < 1:
        raise ValueError(f"fps must be a positive integer, got {fps!r}")


def _as_frame(frame: np.ndarray, what: str) -> np.ndarray:
    arr = np.asarray(frame)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
        raise ValueError(
            f"{what} must be RGB uint8 arrays of shape (H, W, 3), got dtype {arr.dtype} and shape {arr.shape}"
        )
    return arr


def save_png(frame: np.ndarray, path: str | Path) -> Path:
    """Writes one RGB frame as a PNG (creating parent folders) and returns its path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(_as_frame(frame, "frame")).save(out, format="PNG")
    return out


def save_gif(frames: Sequence[np.ndarray], path: str | Path, fps: int = 8) -> Path:
    """Writes frames as an animated GIF that loops forever (creating parent folders).

    Note: Pillow merges consecutive identical frames into one frame that shows for their summed
    duration, so the file may hold fewer frames than given while playing for the same time.
    """
    if len(frames) == 0:
        raise ValueError("save_gif needs at least one frame")
    _check_fps(fps)
    arrays = [_as_frame(f, "frames") for f in frames]
    if len({a.shape for a in arrays}) != 1:
        raise ValueError(f"all frames must have the same shape, got {sorted({a.shape for a in arrays})}")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    images = [Image.fromarray(a) for a in arrays]
    images[0].save(
        out,
        format="GIF",
        save_all=True,
        append_images=images[1:],
        duration=10 * max(1, round(100 / fps)),  # GIF delays are whole centiseconds
        loop=0,
    )
    return out


def rollout_frames(states: EnvState, tile_size: int = 32) -> list[np.ndarray]:
    """Renders a time-stacked state (every leaf with leading axis T, as `lax.scan` stacks it).

    Returns one frame per time index, as `render_frame` draws it.
    """
    _check_tile_size(tile_size)
    host: EnvState = jax.device_get(states)
    if np.ndim(host.agent_pos) != 3:
        raise ValueError(
            "rollout_frames takes an EnvState stacked over time (agent_pos of shape (T, 2, 2)), "
            f"got agent_pos of shape {np.shape(host.agent_pos)}; use render_frame for one state"
        )
    n = int(np.shape(host.agent_pos)[0])
    frames = []
    for t in range(n):
        one: EnvState = jax.tree.map(lambda x, t=t: x[t], host)
        frames.append(_draw_state(one, tile_size))
    return frames


@partial(jax.jit, static_argnames=("policy", "steps"))
def _rollout(key: jax.Array, level: Level, params: EnvParams, *, policy: str, steps: int) -> EnvState:
    """The reset state and the `steps` states after it, stacked on a leading time axis."""
    k_reset, k_run = jax.random.split(key)
    _, first = reset(k_reset, level, params)

    def body(state: EnvState, k: jax.Array) -> tuple[EnvState, EnvState]:
        if policy == "random":
            actions = jax.random.randint(k, (2,), 0, NUM_ACTIONS, dtype=jnp.int32)
        else:
            actions = scripted_actions(k, state, SCRIPTED_EPSILON)
        nxt = step(k, state, actions, params).state
        return nxt, nxt

    _, rest = jax.lax.scan(body, first, jax.random.split(k_run, steps))
    stacked: EnvState = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b], axis=0), first, rest)
    return stacked


def _join(panels: Sequence[np.ndarray], gap: int, axis: int) -> np.ndarray:
    """Joins RGB frames along `axis` (1: left to right, 0: top to bottom), aligned at the start of the
    other axis, `gap` pixels apart, on the background colour."""
    other = 1 - axis
    shape = [0, 0, 3]
    shape[axis] = sum(p.shape[axis] for p in panels) + gap * (len(panels) - 1)
    shape[other] = max(p.shape[other] for p in panels)
    out = np.empty(shape, np.uint8)
    out[:] = BACKGROUND
    at = 0
    for p in panels:
        if axis == 1:
            out[: p.shape[0], at : at + p.shape[1]] = p
        else:
            out[at : at + p.shape[0], : p.shape[1]] = p
        at += p.shape[axis] + gap
    return out


def side_by_side(panels: Sequence[np.ndarray], gap: int = 8) -> np.ndarray:
    """Joins RGB frames left to right, top-aligned, on the background colour, `gap` pixels apart."""
    return _join(panels, gap, axis=1)


def contact_sheet(frames: Sequence[np.ndarray], columns: int = 4, gap: int = 8) -> np.ndarray:
    """Lays frames out in rows of `columns` (each row as `side_by_side`), rows `gap` pixels apart."""
    if not frames or columns < 1:
        raise ValueError("contact_sheet needs at least one frame and columns >= 1")
    rows = [side_by_side(list(frames[i : i + columns]), gap) for i in range(0, len(frames), columns)]
    return _join(rows, gap, axis=0)


def render_episode_gif(
    level: Level | Sequence[Level],
    path: str | Path,
    *,
    steps: int | None = None,
    policy: str = "random",
    seed: int = 0,
    tile_size: int = 32,
    fps: int = 8,
    params: EnvParams | None = None,
) -> Path:
    """Plays one episode of `steps` steps on `level` and saves it as a GIF (the reset state first).

    Args:
        level: a single `Level`, or several, played side by side in one GIF (one compiled rollout
            serves them all).
        path: where to write the GIF (parent folders are created).
        steps: episode length (default: `params.max_steps`, else 100); the GIF shows `steps + 1`
            states.
        policy: "random" (uniform actions, both seats) or "scripted" (the greedy cook of
            `cec.envs.overcooked.scripted`, with epsilon 0.1).
        seed: PRNG seed for the start facings and the policy.
        tile_size: pixels per cell side.
        fps: GIF frames per second.
        params: dynamics settings (default `EnvParams()`); `max_steps` is set to `steps`.

    Raises:
        ValueError: for an unknown policy, `steps < 1`, a bad tile size or fps, or a batched level;
        `LevelError` for a malformed level.
    """
    levels = [level] if isinstance(level, Level) else list(level)
    if steps is None:
        steps = int(params.max_steps) if params is not None else 100
    if policy not in POLICIES:
        raise ValueError(f"unknown policy {policy!r}; choose one of {', '.join(POLICIES)}")
    if not isinstance(steps, int | np.integer) or isinstance(steps, bool) or steps < 1:
        raise ValueError(f"steps must be an integer >= 1, got {steps!r}")
    _check_tile_size(tile_size)
    _check_fps(fps)
    if not levels:
        raise ValueError("render_episode_gif needs at least one level")
    for lv in levels:
        if np.ndim(lv.grid) != 2:
            raise ValueError(
                f"render_episode_gif takes unbatched Levels, got grid of shape {np.shape(lv.grid)}"
            )
        validate_level(lv)
    params = dataclasses.replace(params or EnvParams(), max_steps=int(steps))
    panels = [
        rollout_frames(
            _rollout(jax.random.PRNGKey(seed), lv, params, policy=policy, steps=int(steps)),
            tile_size,
        )
        for lv in levels
    ]
    frames = [side_by_side(list(at_t)) for at_t in zip(*panels, strict=True)]
    return save_gif(frames, path, fps=fps)
