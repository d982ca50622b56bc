"""Recorded human-human games: import (from overcooked-ai's package), the safe format, the replay check."""

from __future__ import annotations

import io
import json
from dataclasses import replace

import numpy as np
import pytest

from apps import humans
from cec.config import ConfigError
from cec.humans.data import KITCHENS, HumanDataError, load_steps
from cec.humans.replay import replay_steps


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """The first game of each kitchen of both splits, imported: the folder."""
    out = tmp_path_factory.mktemp("humans")
    humans.import_games(out, games_per_kitchen=1, log=io.StringIO())
    return out


def test_import_writes_every_kitchen_of_both_splits(imported):
    meta = json.loads((imported / "meta.json").read_text())
    assert meta["source"]["package"] == "overcooked-ai==1.1.0"
    for split in ("train", "test"):
        steps = load_steps(imported, split)
        counts = steps.counts()
        assert list(counts) == list(KITCHENS)
        for kitchen, c in counts.items():
            assert c["games"] == 1 and c["steps"] > 1000 and c["deliveries"] > 5, (split, kitchen)
        assert meta["splits"][split]["counts"] == counts


def test_every_sampled_recorded_step_replays_exactly_and_the_check_can_fail(imported):
    steps = load_steps(imported, "train")
    for kitchen, r in replay_steps(steps).items():
        assert r.exact == r.steps and not r.classes, (kitchen, dict(r.classes))
    # the same states with each seat given the other's action: the replay notices
    swapped = replace(steps, actions=steps.actions[:, ::-1].copy())
    moved = steps.actions[:, 0] != steps.actions[:, 1]
    result = replay_steps(swapped.select(moved))
    assert all(r.exact < 0.2 * r.steps for r in result.values())
    assert any("agent_pos" in label for r in result.values() for label in r.classes)


def test_a_changed_or_foreign_file_is_refused(imported, tmp_path, monkeypatch):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(imported, copy)
    data = bytearray((copy / "test.npz").read_bytes())
    data[len(data) // 2] ^= 1
    (copy / "test.npz").write_bytes(bytes(data))
    with pytest.raises(HumanDataError, match=r"test.npz is missing or not the file .* describes"):
        load_steps(copy, "test")
    load_steps(copy, "train")  # the other split is untouched
    meta = json.loads((copy / "meta.json").read_text())
    (copy / "meta.json").write_text(json.dumps({**meta, "format": "other/9"}))
    with pytest.raises(HumanDataError, match="not of format cec-humans/1"):
        load_steps(copy, "train")
    with pytest.raises(HumanDataError, match="does not exist; run `cec humans import`"):
        load_steps(tmp_path / "nothing", "train")
    # a pickle that is not overcooked-ai 1.1.0's is never unpickled
    monkeypatch.setitem(humans.PICKLES, "train", (humans.PICKLES["train"][0], "0" * 64))
    with pytest.raises(ConfigError, match="refusing to unpickle"):
        humans.read_split("train", games_per_kitchen=1)


def test_values_out_of_range_are_refused(imported, tmp_path):
    from cec.humans.data import save_steps

    steps = load_steps(imported, "train")
    bad = replace(steps, pot=np.full_like(steps.pot, 99))
    with pytest.raises(HumanDataError, match=r"array pot has values outside \[0, 23\]"):
        save_steps({"train": bad}, tmp_path, source={})


def test_proxies_are_zoo_entries_that_play(imported, tmp_path):
    """`cec humans bc` on one kitchen: bc and hp proxies, their figures, a manifest that loads and plays."""
    import yaml

    from cec.agents.policy import load_policies
    from cec.agents.zoo import load_zoo
    from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels
    from cec.humans.bc import BCConfig

    out = tmp_path / "proxies"
    manifest = humans.train_proxies(
        imported, out, kitchens=["cramped_room"], config=BCConfig(epochs=2), log=io.StringIO()
    )
    raw = yaml.safe_load(manifest.read_text())["policies"]
    assert [(p["name"], p["algorithm"], p["levels"]) for p in raw] == [
        ("bc_cramped_room", "human_proxy", ["cramped_room"]),
        ("hp_cramped_room", "human_proxy", ["cramped_room"]),
    ]
    figures = json.loads((out / "bc.json").read_text())["proxies"]
    assert [figures[n]["trained_on"] for n in ("bc_cramped_room", "hp_cramped_room")] == ["train", "test"]
    for f in figures.values():
        assert 1 <= f["best_epoch"] <= 2 and 0 < f["cross_entropy"] < 1.8 and len(f["history"]) == 2
    policies, skipped = load_policies(load_zoo(manifest))
    assert not skipped and {p.algorithm for p in policies} == {"human_proxy"}
    config = EvalConfig(levels="cramped_room", episodes=1, max_steps=20)
    table = crossplay(policies, eval_levels("overcooked", "cramped_room"), config)
    assert not table.skipped and set(table.policy_a) == {"bc_cramped_room", "hp_cramped_room"}
    with pytest.raises(ConfigError, match=r"unknown kitchen\(s\) \['kitchen_9'\]"):
        humans.train_proxies(imported, out, kitchens=["kitchen_9"])


def test_bc_clones_with_a_presets_network_and_refuses_one_with_memory(capsys):
    """A proxy plays only with agents of its architecture: `--preset` clones with theirs; an LSTM network
    (cloned step by step, it would play with a memory it never trained) is refused before any work."""
    from apps.cli import main
    from cec.humans.bc import PROXY_NETWORK

    assert humans._preset_network("configs/train/quick_cpu.yaml")["network"] != PROXY_NETWORK
    e3t = humans._preset_network("configs/train/e3t.yaml")["network"]
    assert e3t.partner_history == 0  # the proxy without E3T's partner model: cross-play embeds one
    assert (
        main(["humans", "bc", "--preset", "configs/train/cec_overcooked.yaml", "--data", "/nonexistent"]) == 2
    )
    err = capsys.readouterr().err
    assert "cec humans bc: error: a human proxy's network has no memory" in err and "LSTM of 256" in err
