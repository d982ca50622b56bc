"""Every training preset in configs/train loads, and its algorithm, partner and paths fit together."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from cec.config import load_config
from cec.levels.classic import CLASSIC_ASCII
from cec.training.config import ALGORITHMS, TrainConfig

PRESETS = sorted((Path(__file__).resolve().parents[3] / "configs" / "train").glob("*.yaml"))


def _load(name: str) -> TrainConfig:
    return load_config(TrainConfig, PRESETS[0].parent / f"{name}.yaml")


def _run_path(config: TrainConfig) -> str:
    """Where `train()` writes a preset's run (relative to the directory `cec train` runs in)."""
    return str(Path(config.run_dir) / config.run_name)


#: The presets that fine-tune the shipped generalists, and the algorithm label of the group they start from.
SHIPPED_FINETUNES = {"cec_finetune_shipped": "cec", "cec_finetune_teacher": "cec_teacher"}


@pytest.mark.parametrize("path", PRESETS, ids=[p.stem for p in PRESETS])
def test_preset_loads_and_is_consistent(path):
    config = load_config(TrainConfig, path)  # populations / init_from need not exist yet
    kind, procedural = ALGORITHMS[config.algorithm]
    assert config.partner.kind == kind and config.env.procedural == procedural
    if config.algorithm == "fcp":  # the population is the IPPO preset's run of the same game and levels
        ippo = _load(path.stem.replace("fcp", "ippo"))
        assert (ippo.algorithm, ippo.env, ippo.network_config) == ("ippo", config.env, config.network_config)
        assert [e.run for e in config.partner.population] == [_run_path(ippo)]
        assert all(e.checkpoints == ("first", "middle", "last") for e in config.partner.population)
    if path.stem in SHIPPED_FINETUNES:  # seed i from the i-th shipped seed of a group, with their network
        from cec.agents.policy import load_policy
        from cec.agents.zoo import SHIPPED, load_zoo

        shipped = [e for e in load_zoo(SHIPPED) if e.algorithm == SHIPPED_FINETUNES[path.stem]]
        assert config.init_from_paths == tuple(f"cec/shipped/{e.name}" for e in shipped)
        assert config.num_seeds == len(shipped)
        assert all(load_policy(e).network == config.network_config for e in shipped)
        # a teacher, if any, fades out over exactly the fine-tuning
        assert config.ppo.teacher_coef == 0 or config.ppo.teacher_anneal_env_steps == config.total_env_steps
    elif config.algorithm == "cec_finetune":  # from the CEC preset's run, 1e8 steps at a tenth of its LR
        cec = _load("cec_overcooked")
        assert config.init_from == _run_path(cec) and config.network_config == cec.network_config
        assert config.total_env_steps == 100_000_000 and config.ppo.lr == pytest.approx(cec.ppo.lr / 10)
        assert config.env.params.max_steps == cec.env.params.max_steps
    if config.algorithm in ("e3t", "cec_e3t"):
        assert 0.0 < config.partner.epsilon < 1.0
    if path.stem == "cec_overcooked_starts":  # the time-to-skill recipe with random start items only
        recipe = _load("cec_overcooked_tts")
        params = dataclasses.replace(recipe.env.overcooked, random_start_items=0.1)
        assert config == dataclasses.replace(recipe, env=dataclasses.replace(recipe.env, overcooked=params))
    if config.algorithm == "cec_scripted":  # a lever on a recipe: everything else equal
        recipe = _load("cec_overcooked_tts")
        if path.stem == "cec_starts_cook_anneal":  # lever (m) with the cook's share annealed, else equal
            cook = _load("cec_starts_cook_handover")
            annealed = dataclasses.replace(
                cook.partner, scripted_share=1.0, scripted_anneal_env_steps=7_864_320
            )
            assert config == dataclasses.replace(cook, partner=annealed)
            assert config.partner.scripted_anneal_env_steps == config.total_env_steps * 3 // 4
            return
        if path.stem == "cec_starts_cook_handover":  # on the random-start preset, with coverage 0.5
            recipe = _load("cec_overcooked_starts")
            generator = dataclasses.replace(recipe.env.generator, handover_share=0.5)
            recipe = dataclasses.replace(recipe, env=dataclasses.replace(recipe.env, generator=generator))
        assert config == dataclasses.replace(recipe, algorithm=config.algorithm, partner=config.partner)


def test_every_algorithm_has_presets_on_every_classic_kitchen():
    names = {p.stem for p in PRESETS}
    for layout in CLASSIC_ASCII:
        for algorithm in ("ippo", "fcp", "e3t", "cec_finetune"):
            assert f"{algorithm}_{layout}" in names
    assert {"cec_overcooked", "cec_e3t", "dd_ippo_quick", "dd_fcp_quick", "dd_e3t_quick"} <= names
    assert {load_config(TrainConfig, p).algorithm for p in PRESETS} == set(ALGORITHMS)


def test_egocentric_networks_are_refused_outside_overcooked():
    from cec.config import ConfigError

    assert _load("cec_overcooked_cpu").network_config.egocentric
    with pytest.raises(ConfigError, match="own cell only in Overcooked"):
        load_config(TrainConfig, PRESETS[0].parent / "dd_cec_cpu.yaml", ["network_overrides.egocentric=true"])


def test_region_channels_are_refused_outside_overcooked():
    from cec.config import ConfigError

    dd = PRESETS[0].parent / "dd_cec_cpu.yaml"
    with pytest.raises(ConfigError, match="region_channels reads Overcooked's observation"):
        load_config(TrainConfig, dd, ["network_overrides.region_channels=true"])
