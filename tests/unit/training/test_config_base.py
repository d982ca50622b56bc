"""Config files as overlays: `base:` names the file an overlay builds on; chains merge, loops and missing
bases are refused naming the file, and unknown keys are refused wherever in the chain they stand."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from cec.config import BASE_CHAIN_MAX, ConfigError, load_config, read_config
from cec.envs.overcooked import EnvParams
from cec.training.config import TrainConfig

REPO = Path(__file__).resolve().parents[3]

BASE = """\
algorithm: ippo
num_envs: 16
env:
  name: overcooked
  levels: cramped_room
  overcooked:
    max_steps: 100
    soup_pickup_reward: 5.0
ppo:
  lr: 0.001
  ent_coef: 0.01
checkpoint:
  milestones: [0.0, 0.5, 1.0]
"""


def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_an_overlay_gives_only_what_differs_and_mappings_merge_key_by_key(tmp_path: Path) -> None:
    _write(tmp_path, "base.yaml", BASE)
    overlay = "base: base.yaml\nenv:\n  overcooked:\n    max_steps: 400\nppo:\n  lr: 3e-4\n"
    over = _write(tmp_path, "over.yaml", overlay)
    base, config = load_config(TrainConfig, tmp_path / "base.yaml"), load_config(TrainConfig, over)
    assert config.env.params.max_steps == 400 and config.ppo.lr == pytest.approx(3e-4)
    # every value the overlay does not name is the base's, nested ones included
    assert config.env.overcooked.soup_pickup_reward == 5.0 and config.ppo.ent_coef == 0.01
    assert config == dataclasses.replace(
        base,
        env=dataclasses.replace(base.env, overcooked=dataclasses.replace(base.env.overcooked, max_steps=400)),
        ppo=dataclasses.replace(base.ppo, lr=3e-4),
    )


def test_a_list_in_an_overlay_replaces_the_bases_whole(tmp_path: Path) -> None:
    _write(tmp_path, "base.yaml", BASE)
    over = _write(tmp_path, "over.yaml", "base: base.yaml\ncheckpoint:\n  milestones: [1.0]\n")
    assert load_config(TrainConfig, over).checkpoint.milestones == (1.0,)


def test_chains_merge_in_order_and_overrides_come_last(tmp_path: Path) -> None:
    _write(tmp_path, "a/base.yaml", BASE)
    _write(tmp_path, "a/b/middle.yaml", "base: ../base.yaml\nnum_envs: 32\nppo:\n  lr: 0.002\n")
    top = _write(tmp_path, "top.yaml", "base: a/b/middle.yaml\nnum_envs: 64\n")
    config = load_config(TrainConfig, top, ["ppo.ent_coef=0.02"])
    assert (config.num_envs, config.ppo.lr, config.ppo.ent_coef) == (64, 0.002, 0.02)
    assert "base" not in read_config(top)  # the key is the loader's, never a field


def test_a_base_is_found_relative_to_the_repository(tmp_path: Path) -> None:
    over = _write(tmp_path, "mine.yaml", "base: configs/train/cramped_room_ci.yaml\nnum_envs: 8\n")
    shipped = load_config(TrainConfig, REPO / "configs/train/cramped_room_ci.yaml")
    assert load_config(TrainConfig, over) == dataclasses.replace(shipped, num_envs=8)


def test_the_overlays_folder_comes_before_the_repository(tmp_path: Path) -> None:
    _write(tmp_path, "configs/train/cramped_room_ci.yaml", BASE)  # same relative path as the repository's
    over = _write(tmp_path, "over.yaml", "base: configs/train/cramped_room_ci.yaml\n")
    assert load_config(TrainConfig, over).num_envs == 16


def test_a_missing_base_is_refused_naming_the_overlay_and_the_base(tmp_path: Path) -> None:
    over = _write(tmp_path, "over.yaml", "base: nowhere.yaml\nnum_envs: 8\n")
    with pytest.raises(ConfigError, match=r"over\.yaml'.*its base 'nowhere\.yaml' does not exist"):
        load_config(TrainConfig, over)
    for bad in ("base: 3\n", "base:\n", "base: ''\n", "base: [a.yaml]\n"):
        _write(tmp_path, "bad.yaml", bad)
        with pytest.raises(ConfigError, match=r"bad\.yaml'.*base must be the path"):
            load_config(TrainConfig, tmp_path / "bad.yaml")


def test_a_base_that_is_not_a_config_is_refused_naming_it(tmp_path: Path) -> None:
    _write(tmp_path, "list.yaml", "- 1\n")
    over = _write(tmp_path, "over.yaml", "base: list.yaml\n")
    with pytest.raises(ConfigError, match=r"list\.yaml' must hold a mapping"):
        load_config(TrainConfig, over)
    (tmp_path / "folder.yaml").mkdir()
    _write(tmp_path, "over2.yaml", "base: folder.yaml\n")
    with pytest.raises(ConfigError, match=r"folder\.yaml' does not exist"):  # only files are bases
        load_config(TrainConfig, tmp_path / "over2.yaml")


@pytest.mark.parametrize("length", [1, 2, 3])
def test_a_chain_that_loops_is_refused_naming_the_files(tmp_path: Path, length: int) -> None:
    names = [f"c{i}.yaml" for i in range(length)]
    for i, name in enumerate(names):
        _write(tmp_path, name, f"base: {names[(i + 1) % length]}\nnum_envs: {i + 1}\n")
    with pytest.raises(ConfigError, match=r"c0\.yaml'.*base chain loops \(.*c0\.yaml"):
        load_config(TrainConfig, tmp_path / "c0.yaml")


def test_a_chain_longer_than_the_cap_is_refused(tmp_path: Path) -> None:
    _write(tmp_path, f"c{BASE_CHAIN_MAX - 1}.yaml", BASE)
    for i in range(BASE_CHAIN_MAX - 1):
        _write(tmp_path, f"c{i}.yaml", f"base: c{i + 1}.yaml\n")
    assert load_config(TrainConfig, tmp_path / "c0.yaml").num_envs == 16  # exactly the cap: read
    _write(tmp_path, "c-1.yaml", "base: c0.yaml\n")
    with pytest.raises(ConfigError, match=f"longer than {BASE_CHAIN_MAX} files"):
        load_config(TrainConfig, tmp_path / "c-1.yaml")


def test_unknown_keys_are_refused_in_the_overlay_and_in_the_base(tmp_path: Path) -> None:
    _write(tmp_path, "base.yaml", BASE)
    _write(tmp_path, "over.yaml", "base: base.yaml\nppo:\n  lrr: 0.1\n")
    with pytest.raises(ConfigError, match="unknown key 'ppo.lrr'.*did you mean 'lr'"):
        load_config(TrainConfig, tmp_path / "over.yaml")
    _write(tmp_path, "typo_base.yaml", BASE + "num_env: 3\n")
    _write(tmp_path, "over2.yaml", "base: typo_base.yaml\n")
    with pytest.raises(ConfigError, match="unknown key 'num_env'"):
        load_config(TrainConfig, tmp_path / "over2.yaml")
    with pytest.raises(ConfigError, match="unknown key 'base'"):  # an override is no file: no base there
        load_config(TrainConfig, tmp_path / "base.yaml", ["base=other.yaml"])


def test_a_key_twice_in_a_base_is_refused_naming_the_base(tmp_path: Path) -> None:
    _write(tmp_path, "base.yaml", "max_steps: 100\nmax_steps: 200\n")
    _write(tmp_path, "over.yaml", "base: base.yaml\n")
    with pytest.raises(ConfigError, match=r"base\.yaml'.*'max_steps' is given twice"):
        load_config(EnvParams, tmp_path / "over.yaml")
