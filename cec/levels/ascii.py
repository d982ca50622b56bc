"""ASCII codec for levels: one character per cell, one line per row.

    W counter      O onion pile   B plate pile (bowls)   P pot   X goal (delivery)   ' ' floor
    0 / 1          seat 0 / seat 1 start cell (on floor)
    A              an agent start cell; with two `A`s, the first in reading order is seat 0

An optional last line `facing: <d0> <d1>` (each one of N S E W) gives the start facings; without it
both agents face north. `to_ascii` always writes seats as digits and writes the facing line only when
a facing is not north, so `from_ascii(to_ascii(level)) == level` for every valid level.
"""

from __future__ import annotations

import numpy as np

from cec.levels.level import Direction, Level, LevelError, Tile

TILE_CHARS: dict[str, Tile] = {
    " ": Tile.FLOOR,
    "W": Tile.COUNTER,
    "O": Tile.ONION_PILE,
    "B": Tile.PLATE_PILE,
    "P": Tile.POT,
    "X": Tile.GOAL,
}
CHAR_OF_TILE: dict[Tile, str] = {t: c for c, t in TILE_CHARS.items()}
AGENT_CHARS = "01A"
FACING_CHARS = {
    "N": Direction.NORTH,
    "S": Direction.SOUTH,
    "E": Direction.EAST,
    "W": Direction.WEST,
}
CHAR_OF_FACING = {d: c for c, d in FACING_CHARS.items()}


def from_ascii(text: str) -> Level:
    """Parses an ASCII kitchen (see module docstring) into a validated `Level`.

    Raises:
        LevelError: on unknown characters, ragged rows, a bad agent count or facing line, or any
            structural problem `validate_level` finds. The message names the row/column at fault.
    """
    lines = text.split("\n")
    while lines and not lines[0].strip():
        lines.pop(0)
    while lines and not lines[-1].strip():
        lines.pop()
    facings = [Direction.NORTH, Direction.NORTH]
    if lines and lines[-1].strip().lower().startswith("facing:"):
        facings = _parse_facing(lines.pop().strip())
    if not lines:
        raise LevelError("the ASCII layout is empty; give one line of tiles per kitchen row")

    width = len(lines[0])
    for r, line in enumerate(lines):
        if len(line) != width:
            raise LevelError(
                f"row {r} has {len(line)} characters but row 0 has {width}; every row must have the "
                "same width (write floor as spaces, including trailing ones)"
            )
    grid = np.zeros((len(lines), width), dtype=np.int64)
    seats: dict[str, list[tuple[int, int]]] = {"0": [], "1": [], "A": []}
    for r, line in enumerate(lines):
        for c, ch in enumerate(line):
            if ch in AGENT_CHARS:
                seats[ch].append((r, c))
                grid[r, c] = Tile.FLOOR
            elif ch in TILE_CHARS:
                grid[r, c] = TILE_CHARS[ch]
            else:
                raise LevelError(
                    f"unknown character {ch!r} at row {r}, column {c}; use one of "
                    "'W' counter, 'O' onion pile, 'B' plate pile, 'P' pot, 'X' goal, ' ' floor, "
                    "'0'/'1' (or 'A') agents"
                )
    if seats["A"] and (seats["0"] or seats["1"]):
        raise LevelError("mix of 'A' and '0'/'1' agent marks; mark both agents the same way")
    if seats["A"]:
        agents = seats["A"]
        if len(agents) != 2:
            raise LevelError(f"found {len(agents)} 'A' agent marks; a kitchen has exactly 2 agents")
    else:
        for seat in "01":
            if len(seats[seat]) != 1:
                raise LevelError(
                    f"found {len(seats[seat])} marks for seat {seat}; mark exactly one '0' and one '1'"
                )
        agents = [seats["0"][0], seats["1"][0]]
    return Level.create(grid, agents, facings)


def to_ascii(level: Level) -> str:
    """Writes a single level as ASCII (the kitchen only, without the frame padding)."""
    grid = level.kitchen()
    rows = [[CHAR_OF_TILE[Tile(int(v))] for v in row] for row in grid]
    for seat, (r, c) in enumerate(np.asarray(level.agent_pos).tolist()):
        rows[r][c] = str(seat)
    text = "\n".join("".join(row) for row in rows)
    dirs = [Direction(int(d)) for d in np.asarray(level.agent_dir)]
    if any(d != Direction.NORTH for d in dirs):
        text += "\nfacing: " + " ".join(CHAR_OF_FACING[d] for d in dirs)
    return text


def _parse_facing(line: str) -> list[Direction]:
    parts = line.split(":", 1)[1].split()
    if len(parts) != 2 or any(p.upper() not in FACING_CHARS for p in parts):
        raise LevelError(
            f"bad facing line {line!r}; write e.g. 'facing: N E' with one of N S E W for each seat"
        )
    return [FACING_CHARS[p.upper()] for p in parts]
