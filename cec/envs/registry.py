"""The games by name: `GAMES` and `game(name)`."""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

from cec.config import ConfigError
from cec.envs import dual_destination, overcooked
from cec.envs.base import Game

#: Every game, by its name, in a stable order (Overcooked first).
GAMES: Mapping[str, Game] = MappingProxyType({g.name: g for g in (overcooked.GAME, dual_destination.GAME)})


def game(name: str) -> Game:
    """The game called `name`; `ConfigError` naming the known games otherwise."""
    try:
        return GAMES[name]
    except KeyError:
        raise ConfigError(f"unknown game {name!r}; choose one of {list(GAMES)}") from None
