"""The held-out evaluation set: defined once, stable, solvable, and reproducible from its seeds."""

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
    assert heldout_build.render_file(heldout_build.build_generated()) == heldout.DATA.read_text()


def test_host_and_jax_fingerprints_agree() -> None:
    batch = heldout.heldout_batch()
    np.testing.assert_array_equal(np.asarray(jax.vmap(fingerprint)(batch)), heldout.heldout_fingerprints())
    assert len({tuple(r) for r in heldout.heldout_fingerprints().tolist()}) == 105


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
