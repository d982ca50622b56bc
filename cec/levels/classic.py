"""The five classic Overcooked kitchens, as in Overcooked-AI / JaxMARL, in ASCII (see `cec.levels.ascii`).

Each kitchen keeps its original size, objects and start cells (JaxMARL 0.2.0's layouts), and is placed in
the top-left corner of the 9x9 frame padded with counters. Unlike the paper's code we do not add a second,
unreachable copy of every object: a `Level` holds any number of each object, so the classic kitchens
play exactly as the originals.
"""

from __future__ import annotations

from cec.levels.ascii import from_ascii
from cec.levels.level import Level

CLASSIC_ASCII: dict[str, str] = {
    "cramped_room": """
WWPWW
O0 1O
W   W
WBWXW
""",
    "asymm_advantages": """
WWWWWWWWW
O WXWOW X
W   P   W
W 0 P1  W
WWWBWBWWW
""",
    "coord_ring": """
WWWPW
W 0 P
B1W W
O   W
WOXWW
""",
    "forced_coord": """
WWWPW
O W1P
O0W W
B W W
WWWXW
""",
    "counter_circuit": """
WWWPPWWW
W 0    W
B WWWW X
W     1W
WWWOOWWW
""",
}

#: Display names, in the paper's order.
CLASSIC_NAMES: dict[str, str] = {
    "asymm_advantages": "Asymmetric Advantages",
    "coord_ring": "Coordination Ring",
    "counter_circuit": "Counter Circuit",
    "cramped_room": "Cramped Room",
    "forced_coord": "Forced Coordination",
}


def classic_level(name: str) -> Level:
    """The classic kitchen `name` (one of `CLASSIC_ASCII`) as a `Level`."""
    if name not in CLASSIC_ASCII:
        raise KeyError(f"unknown classic layout {name!r}; choose one of {sorted(CLASSIC_ASCII)}")
    return from_ascii(CLASSIC_ASCII[name])


def classic_levels() -> dict[str, Level]:
    """All five classic kitchens, keyed by name."""
    return {name: classic_level(name) for name in CLASSIC_ASCII}
