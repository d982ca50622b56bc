"""Strict typed config loading: presets, overrides, and clear errors for every kind of mistake."""

from __future__ import annotations

from pathlib import Path

import pytest

from cec.config import ConfigError, load_config
from cec.envs.overcooked import EnvParams

CONFIGS = Path(__file__).resolve().parents[3] / "configs" / "env"


@pytest.mark.parametrize("preset", sorted(p.name for p in CONFIGS.glob("*.yaml")))
def test_every_env_preset_loads(preset: str) -> None:
    params = load_config(EnvParams, CONFIGS / preset)
    assert params.max_steps in (100, 200, 256, 400)


def test_presets_set_the_paper_episode_lengths() -> None:
    assert load_config(EnvParams, CONFIGS / "cec_paper.yaml").max_steps == 100
    assert load_config(EnvParams, CONFIGS / "reference_eval.yaml").max_steps == 256
    assert load_config(EnvParams).max_steps == 400
    human = load_config(EnvParams, CONFIGS / "human_study.yaml")
    assert human.max_steps == 200 and human.random_start_facing is False


def test_overrides_apply_after_the_file() -> None:
    params = load_config(EnvParams, CONFIGS / "cec_paper.yaml", ["max_steps=256", "soup_pickup_reward=5"])
    assert params.max_steps == 256 and params.soup_pickup_reward == 5.0
    assert isinstance(params.soup_pickup_reward, float)


def test_exponent_notation_is_a_number(tmp_path: Path) -> None:
    """`3e-4` is how papers write learning rates; YAML 1.1 reads it as a string unless it has a dot."""
    from cec.training.config import TrainConfig

    base = ["algorithm=ippo", "env.levels=cramped_room"]
    assert load_config(TrainConfig, None, [*base, "ppo.lr=3e-4"]).ppo.lr == pytest.approx(3e-4)
    path = tmp_path / "lr.yaml"
    path.write_text("algorithm: ippo\nenv:\n  levels: cramped_room\nppo:\n  lr: 2.5E-4\n  max_grad_norm: 1e0")
    config = load_config(TrainConfig, path)
    assert config.ppo.lr == pytest.approx(2.5e-4) and config.ppo.max_grad_norm == 1.0
    with pytest.raises(ConfigError, match="ppo.lr must be a number, got '3e-4x'"):
        load_config(TrainConfig, None, [*base, "ppo.lr=3e-4x"])
    assert load_config(TrainConfig, None, [*base, "name=1e3"]).name == "1e3"  # only float fields convert


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["max_step=3"], "unknown key 'max_step' for EnvParams; did you mean 'max_steps'"),
        (["max_steps=1.5"], "max_steps must be an integer"),
        (["max_steps=true"], "max_steps must be an integer"),
        (["random_start_facing=1"], "random_start_facing must be true or false"),
        (["delivery_reward=lots"], "delivery_reward must be a number"),
        (["max_steps"], "not of the form key=value"),
    ],
)
def test_bad_overrides_name_the_key(overrides: list[str], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_config(EnvParams, None, overrides)


def test_bad_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(EnvParams, tmp_path / "missing.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="mapping of fields"):
        load_config(EnvParams, tmp_path / "list.yaml")
    (tmp_path / "broken.yaml").write_text("max_steps: [1,\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(EnvParams, tmp_path / "broken.yaml")


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["num_envs=["], "override 'num_envs=\\[': the value is not valid YAML"),
        (["ppo.lr=.nan"], "ppo.lr must be a finite number"),
        (["ppo.lr=.inf"], "ppo.lr must be a finite number"),
        (["env.overcooked.delivery_reward=-.inf"], "delivery_reward must be a finite number"),
        (["ppo.max_grad_norm=-1"], "need max_grad_norm > 0"),
        (["ppo.ent_coef=-0.1"], "ent_coef, vf_coef, partner_coef, adam_eps >= 0"),
        (["name=../../etc"], "cannot be a file or folder name"),
        (["name=runs/x"], "cannot be a file or folder name"),
        (["name=.."], "cannot be a file or folder name"),
    ],
)
def test_training_values_that_would_be_silently_wrong_are_refused(overrides: list[str], message: str) -> None:
    from cec.training.config import TrainConfig

    with pytest.raises(ConfigError, match=message):
        load_config(TrainConfig, None, ["algorithm=ippo", "env.levels=cramped_room", *overrides])


def test_a_key_given_twice_in_a_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "twice.yaml"
    path.write_text("max_steps: 100\ndelivery_reward: 20\nmax_steps: 400\n")
    with pytest.raises(ConfigError, match="key 'max_steps' is given twice \\(line 3\\)"):
        load_config(EnvParams, path)
    nested = tmp_path / "nested.yaml"
    nested.write_text("env:\n  overcooked:\n    max_steps: 100\n    max_steps: 400\n")
    from cec.training.config import TrainConfig

    with pytest.raises(ConfigError, match="given twice"):
        load_config(TrainConfig, nested)
