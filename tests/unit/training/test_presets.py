"""Every training preset in configs/train (and every research preset in research/configs) loads, its
algorithm, partner and paths fit together, and no two product presets differ in only one value."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path
from typing import Any

import pytest

from cec.config import load_config
from cec.levels.classic import CLASSIC_ASCII
from cec.training.config import ALGORITHMS, TrainConfig

REPO = Path(__file__).resolve().parents[3]
PRESETS = sorted((REPO / "configs" / "train").glob("*.yaml"))
RESEARCH = sorted((REPO / "research" / "configs").glob("*.yaml"))

#: One preset per algorithm of one classic kitchen: the kitchen is an override (`env.levels=<kitchen>`;
#: cramped_room when none is given), and FCP's population the IPPO preset's run there (`partner.population`).
PER_KITCHEN = ("ippo", "fcp", "e3t", "cec_finetune")

#: The presets that fine-tune the shipped generalists, and the algorithm label of the group they start from.
SHIPPED_FINETUNES = {"cec_finetune_shipped": "cec", "cec_finetune_teacher": "cec_teacher"}


def _load(name: str, overrides: tuple[str, ...] = ()) -> TrainConfig:
    return load_config(TrainConfig, PRESETS[0].parent / f"{name}.yaml", list(overrides))


def _run_path(config: TrainConfig) -> str:
    """Where `train()` writes a preset's run (relative to the directory `cec train` runs in)."""
    return str(Path(config.run_dir) / config.run_name)


def _flat(value: Any, prefix: str = "") -> dict[str, Any]:
    """A config as `dataclasses.asdict` gives it, one entry per leaf value (`ppo.lr`, ...)."""
    if not isinstance(value, dict):
        return {prefix: value}
    out: dict[str, Any] = {}
    for key, item in value.items():
        out.update(_flat(item, f"{prefix}.{key}" if prefix else key))
    return out


def _differ(a: TrainConfig, b: TrainConfig) -> list[str]:
    fa, fb = _flat(dataclasses.asdict(a)), _flat(dataclasses.asdict(b))
    return sorted(k for k in fa.keys() | fb.keys() if fa.get(k, "<unset>") != fb.get(k, "<unset>"))


@pytest.mark.parametrize("path", PRESETS, ids=[p.stem for p in PRESETS])
def test_preset_loads_and_is_consistent(path):
    config = load_config(TrainConfig, path)  # populations / init_from need not exist yet
    kind, procedural = ALGORITHMS[config.algorithm]
    assert config.partner.kind == kind and config.env.procedural == procedural
    if config.algorithm == "fcp":  # the population is the IPPO preset's run of the same game and levels
        ippo = _load(path.stem.replace("fcp", "ippo"), (f"env.levels={config.env.levels}",))
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


@pytest.mark.parametrize("kitchen", sorted(CLASSIC_ASCII))
def test_one_preset_per_algorithm_serves_every_classic_kitchen(kitchen):
    ippo = _load("ippo", (f"env.levels={kitchen}",))
    assert ippo.run_name == f"ippo-overcooked-{kitchen}-s0" and not ippo.env.procedural
    population = f"partner.population=[{{run: {_run_path(ippo)}}}]"
    fcp = _load("fcp", (f"env.levels={kitchen}", population))
    assert [e.run for e in fcp.partner.population] == [_run_path(ippo)]
    assert fcp.partner.population[0].checkpoints == ("first", "middle", "last")
    for name in PER_KITCHEN:
        config = fcp if name == "fcp" else _load(name, (f"env.levels={kitchen}",))
        assert config.algorithm == name and config.env.levels == kitchen
        network = dataclasses.replace(config.network_config, partner_history=0)  # E3T's model aside
        assert (config.env.name, network) == (ippo.env.name, ippo.network_config)


def test_no_two_presets_differ_in_only_one_value():
    """A preset that changes one value of another is an override (or a research overlay), not a preset."""
    loaded = {p.stem: load_config(TrainConfig, p) for p in PRESETS}
    close = [
        f"{a} and {b} differ only in {_differ(loaded[a], loaded[b])}"
        for a, b in itertools.combinations(loaded, 2)
        if len(_differ(loaded[a], loaded[b])) <= 1
    ]
    assert not close, "; ".join(close)


def test_the_one_value_check_sees_a_one_value_copy():
    """The check above is not vacuous: a copy with one value changed, nested or not, is one difference."""
    assert _differ(_load("ippo"), _load("ippo", ("seed=1",))) == ["seed"]
    assert _differ(_load("ippo"), _load("ippo", ("ppo.lr=0.1",))) == ["ppo.lr"]
    assert _differ(_load("ippo"), _load("ippo")) == []


@pytest.mark.parametrize("path", RESEARCH, ids=[p.stem for p in RESEARCH])
def test_research_presets_load_over_the_product_presets(path):
    config = load_config(TrainConfig, path)
    kind, procedural = ALGORITHMS[config.algorithm]
    assert config.partner.kind == kind and config.env.procedural == procedural
    assert config.network_config == _load("cec_overcooked_tts").network_config  # levers on one recipe


def test_every_algorithm_has_a_preset():
    names = {p.stem for p in PRESETS}
    assert {*PER_KITCHEN, "cec_overcooked", "cec_e3t", "dd_ippo_quick", "dd_fcp_quick", "dd_e3t_quick"} <= (
        names
    )
    assert {load_config(TrainConfig, p).algorithm for p in PRESETS + RESEARCH} == set(ALGORITHMS)


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
