"""Kitchen kinds: which seats can finish a soup alone, and whether the floor loops round an island; the
generator's coverage knob draws kitchens that need a hand-over as often as asked."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from cec.config import ConfigError
from cec.levels import from_ascii, heldout
from cec.levels.classic import classic_levels
from cec.levels.generator import GeneratorConfig, generate_batch, generate_batch_with_info
from cec.levels.heldout import heldout_levels
from cec.levels.kinds import LOOP, Kind, classify, kind_of, kinds_of, subsets, validation_parts


def test_the_classic_kitchens_by_kind() -> None:
    kinds = kinds_of(classic_levels())
    assert kinds["forced_coord"] == (Kind.HANDOVER, False)  # onions and plates left, pots and goal right
    assert kinds["asymm_advantages"] == (Kind.BOTH_ALONE, False)  # split, but each side has everything
    assert kinds["cramped_room"] == (Kind.BOTH_ALONE, False)
    assert kinds["coord_ring"] == (Kind.BOTH_ALONE, True)
    assert kinds["counter_circuit"] == (Kind.BOTH_ALONE, True)


def test_one_seat_alone_and_a_loop_only_round_a_free_island() -> None:
    one = from_ascii("WWWWWW\nO0WWOW\nW WB1X\nWWWWPW")  # seat 0 reaches only an onion pile
    out = classify(one)
    assert int(out.kind) == Kind.ONE_ALONE and np.asarray(out.alone).tolist() == [False, True]
    island = from_ascii("WWOWW\nW0  W\nW W W\nW  1P\nWXBWW")  # floor on all 8 sides of (2, 2)
    assert kind_of(island) == (Kind.BOTH_ALONE, True)
    # the goal at (3, 1) touches the island diagonally: no way round between them, so no loop
    assert kind_of(from_ascii("WWOWW\nW0  W\nW W W\nWX 1P\nWWBWW")) == (Kind.BOTH_ALONE, False)


def test_subsets_name_every_kind_present_and_the_loops() -> None:
    levels = dict(heldout_levels())
    parts = subsets(levels)
    kinds = kinds_of(levels)
    assert set(parts) <= {k.label for k in Kind} | {LOOP}
    assert sorted(n for k in Kind for n in parts.get(k.label, [])) == sorted(levels)
    assert "forced_coord" in parts[Kind.HANDOVER.label] and "coord_ring" in parts[LOOP]
    assert all(kinds[n][0] == Kind.HANDOVER for n in parts[Kind.HANDOVER.label])
    assert len(parts[Kind.HANDOVER.label]) == 24  # forced_coord and 23 generated validation kitchens


def _handover_share(config: GeneratorConfig, n: int = 4096) -> float:
    levels = generate_batch(jax.random.PRNGKey(5), n, config)
    return float(np.mean(np.asarray(jax.vmap(classify)(levels).kind) == Kind.HANDOVER))


def test_handover_share_draws_that_many_more_handover_kitchens() -> None:
    base = _handover_share(GeneratorConfig())
    assert 0.15 < base < 0.27  # about one in five as they come
    for share in (0.5, 1.0):
        expected = share + (1 - share) * base
        assert abs(_handover_share(GeneratorConfig(handover_share=share)) - expected) < 0.04


def test_handover_share_zero_draws_exactly_the_default_kitchens() -> None:
    a, ra = generate_batch_with_info(jax.random.PRNGKey(9), 256, GeneratorConfig())
    b, rb = generate_batch_with_info(jax.random.PRNGKey(9), 256, GeneratorConfig(handover_share=0.0))
    np.testing.assert_array_equal(np.asarray(a.grid), np.asarray(b.grid))


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"handover_share": 1.5}, "probability in"),
        ({"handover_share": 0.5, "structures": ("cramped_room", "coord_ring")}, "add forced_coord"),
    ],
)
def test_a_handover_share_that_cannot_be_met_is_refused(changes: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        GeneratorConfig(**changes)  # type: ignore[arg-type]


def test_validation_parts_split_generated_by_kind_and_name_the_rest() -> None:
    parts = validation_parts(dict(heldout_levels()))
    assert len(parts["generated"]) == 100 and parts["classic"] == list(classic_levels())
    assert parts["forced_coord"] == ["forced_coord"]
    assert len(parts[Kind.HANDOVER.label]) == 23  # the generated ones only
    test = validation_parts(dict(heldout.test_levels()))  # a module attribute: pytest collects test_* names
    assert len(test["generated"]) == 100 and all(n.startswith("drawn_") for n in test["drawn"])
