"""Kitchens by file everywhere a level is named (`cec.levels.named`): `cec train env.levels=<folder>`,
`cec eval --levels <folder>`, `cec play` / `cec render` by file; a malformed or unsolvable file is refused
with its reason before any work."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from apps.cli import main
from cec.config import ConfigError, from_dict
from cec.envs.task import EnvConfig, Task
from cec.evaluation.results import read_csv
from cec.levels.ascii import to_ascii
from cec.levels.classic import classic_level
from cec.levels.heldout import heldout_levels
from cec.levels.named import check_level, load_kitchens, resolve_level, resolve_levels
from cec.training.config import TrainConfig
from cec.training.run import train

UNSOLVABLE = "WWWWW\nO0 1O\nWWWWW\nWPBXW\nWWWWW\n"  # pot, plates and goal walled off


@pytest.fixture
def kitchens(tmp_path: Path) -> Path:
    """A folder of two of the user's own kitchens (and a file that is not a kitchen, ignored)."""
    folder = tmp_path / "my_kitchens"
    folder.mkdir()
    (folder / "small.txt").write_text(to_ascii(classic_level("cramped_room")))
    (folder / "odd.txt").write_text(to_ascii(dict(heldout_levels())["generated_003"]))
    (folder / "README.md").write_text("notes, not a kitchen")
    return folder


def _same(a, b) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


def test_names_files_and_folders_resolve_to_the_files_kitchens(kitchens: Path) -> None:
    got = resolve_levels(f"{kitchens},coord_ring")
    assert list(got) == ["odd", "small", "coord_ring"], "a folder's .txt files in name order, then the rest"
    assert _same(got["small"], classic_level("cramped_room"))
    assert list(resolve_levels("small.txt", base_dir=kitchens)) == ["small"], "relative to base_dir"
    with pytest.raises(ConfigError, match="two kitchens are named 'small'"):
        resolve_levels(f"{kitchens},{kitchens / 'small.txt'}")


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (UNSOLVABLE, "not solvable: .*no agent can reach a pot"),
        ("WWWWW\nO0 1O\nW   W\nWBWXW\n", "bad.txt: level has no pot"),
        (b"\x00\xff" * 8, "not a text file"),
        ("W" * 70_000, "at most 65,536 bytes"),
    ],
)
def test_a_bad_kitchen_file_is_refused_with_its_reason(tmp_path: Path, content, reason: str) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(ConfigError, match=reason):
        resolve_levels(str(bad))
    with pytest.raises(ConfigError, match=reason):  # training refuses it when the config is read
        EnvConfig(levels=str(bad))
    with pytest.raises(ConfigError, match=reason):  # and so does `cec play`
        check_level("bad.txt", tmp_path)
    with pytest.raises(ConfigError, match="no kitchen file or folder"):
        resolve_levels(str(tmp_path / "gone.txt"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="has no .txt kitchen files"):
        resolve_levels(str(tmp_path / "empty"))


def test_play_and_the_resolver_read_the_same_kitchen(kitchens: Path) -> None:
    name, level = resolve_level("odd.txt", kitchens, np.random.default_rng(0))
    assert name == "odd" and _same(level, load_kitchens(kitchens / "odd.txt")["odd"])


def test_the_jaxmarl_adapter_takes_a_folder_as_its_kitchens(kitchens: Path) -> None:
    from cec.envs.overcooked.jaxmarl_api import OvercookedMultiAgentEnv

    env = OvercookedMultiAgentEnv(str(kitchens))
    batch = np.asarray(env.levels.grid)
    assert batch.shape[0] == 2 and np.array_equal(batch[1], np.asarray(classic_level("cramped_room").grid))


def test_training_draws_its_levels_from_the_folder_only(kitchens: Path) -> None:
    env = EnvConfig(levels=str(kitchens))
    assert env.procedural and env.levels_label == "my_kitchens"
    assert not EnvConfig(levels=str(kitchens / "small.txt")).procedural, "one file is one fixed level"
    buffers = Task.from_config(env).sample_levels(jax.random.PRNGKey(0), jnp.arange(16), 4)
    grids = np.asarray(buffers.grid).reshape(64, -1)
    want = {name: np.asarray(lv.grid).reshape(-1) for name, lv in load_kitchens(kitchens).items()}
    hits = {name: int((grids == g).all(axis=1).sum()) for name, g in want.items()}
    assert sum(hits.values()) == 64, "every buffered level is one of the files' kitchens"
    assert min(hits.values()) > 10, f"both kitchens are drawn, uniformly: {hits}"
    with pytest.raises(ConfigError, match="algorithm ippo trains on one fixed level"):
        from_dict(TrainConfig, {"algorithm": "ippo", "env": {"levels": str(kitchens)}})


@pytest.mark.slow
def test_cec_trains_on_a_folder_and_cec_eval_scores_it_there(kitchens: Path, tmp_path: Path, capsys) -> None:
    config = from_dict(
        TrainConfig,
        {
            "algorithm": "cec",
            "num_envs": 4,
            "num_steps": 8,
            "total_env_steps": 64,
            "network": "small",
            "env": {"levels": str(kitchens), "overcooked": {"max_steps": 8}},
            "run_dir": str(tmp_path / "runs"),
        },
    )
    assert config.run_name == "cec-overcooked-my_kitchens-s0"
    train(config, progress=False)
    run = tmp_path / "runs" / config.run_name
    zoo = tmp_path / "zoo.json"
    zoo.write_text(json.dumps({"policies": [{"name": "mine", "checkpoint": str(run)}]}))
    out = tmp_path / "results.csv"
    code = main(["eval", "--zoo", str(zoo), "--levels", f"{kitchens},cramped_room", "--episodes", "1",
                 "--max-steps", "8", "--out", str(out)])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    assert sorted(set(read_csv(out).level)) == ["cramped_room", "odd", "small"]

    # An unsolvable kitchen is refused with its reason and exit status 2 before any checkpoint loads: the
    # zoo below names a checkpoint that does not exist, and the error is still the kitchen's.
    (kitchens / "broken.txt").write_text(UNSOLVABLE)
    zoo.write_text(json.dumps({"policies": [{"name": "gone", "checkpoint": str(tmp_path / "gone")}]}))
    assert main(["eval", "--zoo", str(zoo), "--levels", str(kitchens)]) == 2
    err = capsys.readouterr().err
    assert "broken.txt is not solvable" in err and "gone" not in err


def test_one_resolver_names_generated_kitchens_for_training_play_and_the_cli(tmp_path: Path) -> None:
    """`generated:SEED` is the same kitchen wherever it is named: in a training level spec, in `cec play`
    and in `cec render`; `generated:random` only where one kitchen is drawn per use."""
    from apps.cli import main

    by_spec = resolve_levels("generated:12,cramped_room")
    name, level = resolve_level("generated:12")
    assert list(by_spec) == ["generated:12", "cramped_room"] and name == "generated:12"
    assert _same(by_spec["generated:12"], level)
    drawn, _ = resolve_level("generated:random", rng=np.random.default_rng(0))
    assert drawn.startswith("generated:") and drawn != "generated:random"
    with pytest.raises(ConfigError, match="generated:SEED with an integer"):
        resolve_levels("generated:random")
    for bad in ("generated:-1", "generated:x", "generated:99999999999"):
        with pytest.raises(ConfigError, match="generated:SEED"):
            check_level(bad)
    assert main(["render", "generated:12", "--png", str(tmp_path / "k.png")]) == 0
