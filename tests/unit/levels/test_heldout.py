"""The evaluation sets (validation, once called held-out, and test): defined once, stable, solvable,
disjoint, reproducible from their seeds and sources, and never drawn by the generator."""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np
import pytest

from cec.envs import overcooked as oc
from cec.levels import heldout, heldout_build
from cec.levels.fingerprint import content_hash, fingerprint
from cec.levels.solvability import validate_solvable


def test_set_has_the_classics_then_100_generated_distinct_solvable_levels() -> None:
    levels = heldout.heldout_levels()
    names = [n for n, _ in levels]
    assert names[:5] == list(oc.CLASSIC_ASCII) and len(levels) == 105
    assert names[5:] == [f"generated_{i:03d}" for i in range(100)]
    hashes = {content_hash(lv) for _, lv in levels}
    assert len(hashes) == 105
    for _, lv in levels:
        assert validate_solvable(lv) == []


def test_file_matches_its_seeds() -> None:
    assert heldout_build.render_file(heldout_build.build_validation()) == heldout.DATA.read_text()


def test_test_set_is_100_generated_then_the_drawn_kitchens_disjoint_from_validation() -> None:
    levels = heldout.test_levels()
    names = [n for n, _ in levels]
    assert names[:100] == [f"test_{i:03d}" for i in range(100)]
    drawn = names[100:]
    assert len(drawn) >= 10 and all(n.startswith(heldout.DRAWN_PREFIX) for n in drawn)
    assert "drawn_bottleneck" in drawn and not any("cramped_room" in n for n in drawn)
    validation = {content_hash(lv) for _, lv in heldout.heldout_levels()}
    test = {content_hash(lv) for _, lv in levels}
    assert len(test) == len(levels) and not validation & test
    for _, lv in levels:
        assert validate_solvable(lv) == []


def test_test_file_matches_its_seeds_and_the_overcooked_ai_layouts() -> None:
    layouts = heldout_build.overcooked_ai_layouts()
    test, skipped = heldout_build.build_test(layouts)
    recorded = heldout.TEST_DATA.read_text()
    if layouts is None:  # without the peers extra only the generated kitchens can be rebuilt
        recorded = "\n\n".join(b for b in recorded.split("\n\n")[:100]) + "\n"
    else:
        assert skipped["forced_coordination"] == "a classic kitchen or a variant of one"
        assert "tomato" in skipped["cramped_room_tomato"]
    assert heldout_build.render_file(test) == recorded


def test_the_second_test_set_is_fresh_frozen_and_kept_out_of_training() -> None:
    """Drawn for the first release the service made: 100 generated kitchens disjoint from validation and
    the first test set, matching their seeds, resolved as `test2`, and excluded by the generator."""
    from cec.evaluation.crossplay import eval_levels
    from cec.levels.generator import GeneratorConfig, generate_with_info

    levels = heldout.test2_levels()
    assert [n for n, _ in levels] == [f"test2_{i:03d}" for i in range(100)]
    assert heldout_build.render_file(heldout_build.build_test2()) == heldout.TEST2_DATA.read_text()
    earlier = {content_hash(lv) for _, lv in (*heldout.heldout_levels(), *heldout.test_levels())}
    assert not earlier & {content_hash(lv) for _, lv in levels}
    assert eval_levels("overcooked", "test2").names == tuple(n for n, _ in levels)
    assert not any(n.startswith("test2_") for n in eval_levels("overcooked", "test").names)
    # the generator, asked for the first kitchen of test2's own seed, draws another one
    fps = heldout.heldout_fingerprints()
    assert len(fps) == 105 + len(heldout.test_levels()) + 100
    level, info = generate_with_info(jax.random.PRNGKey(heldout.TEST2_SEED_BASE), GeneratorConfig(),
                                          jax.numpy.asarray(fps))  # fmt: skip
    assert int(info.resamples) >= 1 and content_hash(jax.device_get(level)) != content_hash(levels[0][1])


def test_a_drawn_layout_converts_and_one_that_cannot_be_a_kitchen_says_why() -> None:
    text = '{\n "grid": """XXPXX\n   O  2O\n   X1  X\n   XDXSX""",\n "start_all_orders": []\n}'
    level = heldout_build.convert_drawn(text)
    assert level.agent_pos.tolist() == [[2, 1], [1, 3]]  # overcooked-ai's 1 and 2 are seats 0 and 1
    with pytest.raises(heldout_build.LevelError, match="T: a tomato pile"):
        heldout_build.convert_drawn(text.replace("D", "T"))
    with pytest.raises(heldout_build.LevelError, match="does not fit the 9x9 frame"):
        heldout_build.convert_drawn(text.replace("XXPXX", "XXPXXXXXXX"))


def test_host_and_jax_fingerprints_agree() -> None:
    batch = heldout.heldout_batch()
    every = heldout.heldout_fingerprints()  # validation, then both tests: what the generator excludes
    np.testing.assert_array_equal(np.asarray(jax.vmap(fingerprint)(batch)), every[:105])
    assert len(every) == 105 + len(heldout.test_levels()) + len(heldout.test2_levels())
    assert len({tuple(r) for r in every.tolist()}) == len(every)


def test_a_corrupt_file_is_detected(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    text = heldout.DATA.read_text()
    broken = tmp_path / "heldout.txt"
    header, body = text.split("\n", 1)  # "# generated_000 <hash>": the content no longer matches
    broken.write_text(header.rsplit(" ", 1)[0] + " 0123456789abcdef\n" + body)
    monkeypatch.setattr(heldout, "DATA", broken)
    heldout.heldout_levels.cache_clear()
    try:
        with pytest.raises(ValueError, match="does not match its recorded hash"):
            heldout.heldout_levels()
    finally:
        heldout.heldout_levels.cache_clear()
