"""The policies shipped with the package (cec/shipped/): loadable by name with no training and no download,
pinned by SHA-256, and competent: each delivers soups with itself in a classic kitchen it never trained on."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import jax
import numpy as np
import pytest
import yaml

import cec.agents.zoo as zoo_module
from apps.cli import build_parser, parse_args
from cec import checkpoints
from cec.agents.policy import load_policy, resolve_checkpoint, scripted_policy
from cec.agents.zoo import OTHER_KITCHENS, SHIPPED, SHIPPED_BEST, SHIPPED_ZOO, ZooEntry, load_zoo
from cec.config import ConfigError
from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels
from services.play.main import free_play_config, prepare

SHIPPED_NAMES = [e.name for e in load_zoo(SHIPPED)]
CEC_GROUPS = ("cec", "cec_teacher")  # the generalists: the paper's recipe at 758M, the kickstarted release
CEC_NAMES = [e.name for e in load_zoo(SHIPPED) if e.algorithm in CEC_GROUPS]
PROXIES = [e for e in load_zoo(SHIPPED) if e.algorithm == "human_proxy"]
#: The fine-tuned agents' algorithm labels and their names' prefix (from the CEC seeds, the kickstarted ones)
FINETUNE_PREFIX = {"cec_finetune": "ft758m", "cec_finetune_teacher": "ftteach"}
FINETUNED = [e for e in load_zoo(SHIPPED) if e.algorithm in FINETUNE_PREFIX]
CLASSIC = ("cramped_room", "asymm_advantages", "coord_ring", "forced_coord", "counter_circuit")


def test_the_shipped_zoo_exists_and_names_cec_policies_and_a_human_proxy_per_classic_kitchen() -> None:
    assert SHIPPED_ZOO.is_file() and CEC_NAMES
    for entry in load_zoo(SHIPPED):
        assert Path(entry.checkpoint).is_relative_to(SHIPPED_ZOO.parent)  # inside the package
        assert sum(f.stat().st_size for f in Path(entry.checkpoint).iterdir()) < 4 * 2**20  # parameters only
    # the evaluation proxies (`hp_`: cloned from the test games, players the `bc_` proxies never saw)
    assert sorted(level for e in PROXIES for level in e.levels) == sorted(CLASSIC)
    assert all(e.name == f"hp_{e.levels[0]}" for e in PROXIES)
    # CEC-Finetune: per starting group, one partner per classic kitchen, each played only there
    for algorithm, prefix in FINETUNE_PREFIX.items():
        group = [e for e in FINETUNED if e.algorithm == algorithm]
        assert sorted(level for e in group for level in e.levels) == sorted(CLASSIC)
        assert all(e.name == f"{prefix}-{e.levels[0]}" for e in group)


@pytest.mark.parametrize("name", SHIPPED_NAMES)
def test_each_shipped_policy_loads_by_name_with_its_sha256(name: str) -> None:
    (entry,) = [e for e in load_zoo(SHIPPED) if e.name == name]
    path = resolve_checkpoint(name)  # the name stands for the checkpoint
    assert path == Path(entry.checkpoint)
    digest = hashlib.sha256((path / checkpoints.STATE_FILE).read_bytes()).hexdigest()
    assert digest == entry.sha256 == checkpoints.read_meta(path)["sha256"]
    assert load_policy(ZooEntry(name, name)).algorithm == entry.algorithm
    assert load_policy(entry).levels == entry.levels  # a proxy plays the kitchen of its games only


@pytest.mark.parametrize("name", CEC_NAMES)
def test_each_shipped_cec_policy_delivers_with_the_cook(name: str) -> None:
    """What a person playing with it depends on: with a competent partner (the scripted cook) it delivers
    (benchmarks/results/overcooked/shipped: 104-116 per 400 steps on the classic kitchens)."""
    policy = load_policy(ZooEntry(name, name))
    cook = scripted_policy("cook", "cook", env=policy.env, algorithm="cook")
    table = crossplay(
        [policy, cook], eval_levels("overcooked", "cramped_room"),
        EvalConfig(episodes=4, max_steps=400, pairs="with:cook"),
    )  # fmt: skip
    returns = table.returns[table.policy_a != table.policy_b]  # both seat orders
    assert np.mean(returns) >= 40, f"{name} with the cook: {returns} on cramped_room (one soup is 20)"


def test_the_shipped_human_proxies_deliver_with_the_cook_in_their_kitchens() -> None:
    """The evaluator and `cec report` score agents with these: each plays its own kitchen only, and with a
    competent partner soups get delivered there (docs/humans.md has the proxies' figures)."""
    proxies = [load_policy(e) for e in PROXIES]
    cook = scripted_policy("cook", "cook", env=proxies[0].env, algorithm="cook")
    table = crossplay(
        [*proxies, cook], eval_levels("overcooked", ",".join(CLASSIC)),
        EvalConfig(episodes=4, max_steps=400, pairs="with:cook"),
    )  # fmt: skip
    played = table.policy_a != table.policy_b
    for p in proxies:
        mine = played & ((table.policy_a == p.name) | (table.policy_b == p.name))
        assert set(table.level[mine]) == set(p.levels), p.name
        assert np.mean(table.returns[mine]) >= 20, f"{p.name} with the cook: {table.returns[mine]}"


@pytest.mark.parametrize("group", CEC_GROUPS)
def test_the_shipped_cec_agents_cook_with_partners_they_never_met(group: str) -> None:
    """`cec play serve --partner cec` (or `cec_teacher`) draws one of these seeds per round: every pair of two
    different seeds of the group delivers on Cramped Room, the free-play default kitchen
    (benchmarks/results/overcooked/shipped: 61.7 per 400 steps over the 758M seeds' pairs, 4 episodes each,
    both seat orders)."""
    names = [e.name for e in load_zoo(SHIPPED) if e.algorithm == group]
    policies = [load_policy(ZooEntry(name, name)) for name in names]
    config = EvalConfig(episodes=4, max_steps=400, pairs="all")
    table = crossplay(policies, eval_levels("overcooked", "cramped_room"), config)
    xp = table.returns[table.policy_a != table.policy_b]
    assert len(names) >= 4 and xp.size == len(names) * (len(names) - 1) * 4
    assert np.mean(xp) >= 30, f"shipped {group} cross-play on cramped_room: {np.mean(xp)} (one soup is 20)"


def test_a_shipped_policy_whose_state_changed_is_refused(tmp_path: Path) -> None:
    entry = load_zoo(SHIPPED)[0]
    copy = tmp_path / "copy"
    copy.mkdir()
    for f in Path(entry.checkpoint).iterdir():
        data = f.read_bytes()
        (copy / f.name).write_bytes(
            data[:-1] + bytes([data[-1] ^ 1]) if f.name == checkpoints.STATE_FILE else data
        )
    with pytest.raises(checkpoints.CheckpointError, match="corrupt"):
        load_policy(ZooEntry(entry.name, str(copy)))


def test_cec_play_serve_partner_cec_starts_with_the_shipped_agents(tmp_path: Path) -> None:
    args = parse_args(build_parser(), ["play", "serve", "--partner", "cec", "--level", "coord_ring"])
    pools = prepare(free_play_config(args), tmp_path)
    (pool,) = pools.values()
    assert pool.policies and {p.algorithm for p in pool.policies} == {"cec"}
    args = parse_args(build_parser(), ["play", "serve", "--partner", "cec_teacher"])
    (pool,) = prepare(free_play_config(args), tmp_path).values()
    teacher_seeds = [e for e in load_zoo(SHIPPED) if e.algorithm == "cec_teacher"]
    assert len(pool.policies) == len(teacher_seeds) >= 4
    assert {p.algorithm for p in pool.policies} == {"cec_teacher"}
    args = parse_args(build_parser(), ["play", "serve", "--partner", "no_such_agent"])
    with pytest.raises(ConfigError, match="no loadable entry of group 'no_such_agent'"):
        prepare(free_play_config(args), tmp_path)


def test_a_policy_with_non_finite_weights_is_refused_even_with_a_valid_checksum(tmp_path: Path) -> None:
    """A diverged run's parameters (all NaN, the SHA-256 recomputed so the file is 'intact') are not
    evaluated or played as if they were a policy: loading names the array and the cause."""
    from flax import serialization

    entry = load_zoo(SHIPPED)[0]
    policy = load_policy(entry)
    nan = jax.tree.map(lambda x: np.full_like(x, np.nan), policy.params)
    copy = tmp_path / "diverged"
    copy.mkdir()
    data = serialization.msgpack_serialize(serialization.to_state_dict(nan))
    (copy / checkpoints.STATE_FILE).write_bytes(data)
    meta = checkpoints.read_meta(Path(entry.checkpoint))
    meta["sha256"] = hashlib.sha256(data).hexdigest()
    (copy / checkpoints.META_FILE).write_text(json.dumps(meta))
    with pytest.raises(checkpoints.CheckpointError, match=r"non-finite parameters .* are NaN or infinite"):
        load_policy(ZooEntry("diverged", str(copy)))


# per family and kitchen, about 40% of what the shipped fine-tuned agent measured (400 steps; with itself,
# with the cook): benchmarks/results/overcooked/shipped/finetune/summary.json and teacher/summary.json
FINETUNED_AT_LEAST = {
    "ft758m": {
        "cramped_room": (80, 60),
        "asymm_advantages": (80, 90),
        "coord_ring": (100, 55),
        "forced_coord": (40, 10),
        "counter_circuit": (40, 15),
    },
    "ftteach": {
        "cramped_room": (90, 85),
        "asymm_advantages": (140, 120),
        "coord_ring": (100, 100),
        "forced_coord": (110, 100),
        "counter_circuit": (80, 75),
    },
}


@pytest.mark.parametrize("entry", FINETUNED, ids=[e.name for e in FINETUNED])
def test_each_shipped_finetuned_agent_cooks_with_itself_and_with_the_cook_in_its_kitchen(entry) -> None:
    """What a person who plays its kitchen depends on: there it delivers with a copy of itself and with the
    scripted cook (the generalists it started from score less with each other there, 0-81 the CEC seeds)."""
    policy = load_policy(entry)
    (kitchen,) = entry.levels
    cook = scripted_policy("cook", "cook", env=policy.env, algorithm="cook")
    table = crossplay(
        [policy, cook], eval_levels("overcooked", kitchen), EvalConfig(episodes=4, max_steps=400)
    )
    alone = table.returns[(table.policy_a == entry.name) & (table.policy_b == entry.name)]
    with_cook = table.returns[table.policy_a != table.policy_b]
    self_play, cooked = FINETUNED_AT_LEAST[FINETUNE_PREFIX[entry.algorithm]][kitchen]
    assert np.mean(alone) >= self_play, f"{entry.name} with itself: {alone}"
    assert np.mean(with_cook) >= cooked, f"{entry.name} with the cook: {with_cook}"


def test_cec_play_serve_partner_best_plays_the_partner_chosen_for_each_kitchen(tmp_path: Path) -> None:
    """`--partner best` plays, per classic kitchen, what cec/shipped/best.yaml names (a fine-tuned agent, or
    a group of generalist seeds where those cooked more with the validation proxy), and anywhere else the
    generalists it names for every other kitchen."""
    choice = yaml.safe_load(SHIPPED_BEST.read_text())
    assert set(choice) == {*CLASSIC, OTHER_KITCHENS}
    for level in ("forced_coord", "asymm_advantages", "generated_003"):
        args = parse_args(build_parser(), ["play", "serve", "--partner", "best", "--level", level])
        (pool,) = prepare(free_play_config(args), tmp_path).values()
        played = [pool.policies[i] for i in pool.eligible(level)]
        want = choice.get(level, choice[OTHER_KITCHENS])
        assert played and all(want in (p.name, p.algorithm) for p in played), (
            level,
            [p.name for p in played],
        )


def test_a_kitchen_best_yaml_leaves_out_gets_other_kitchens_then_cec(tmp_path: Path, monkeypatch) -> None:
    """A kitchen best.yaml does not name gets its `other_kitchens` entry; without one, the CEC seeds."""
    choice = tmp_path / "best.yaml"
    monkeypatch.setattr(zoo_module, "SHIPPED_BEST", choice)
    choice.write_text(f"forced_coord: ft758m-forced_coord\n{OTHER_KITCHENS}: cec_teacher\n")
    assert zoo_module.best_shipped("forced_coord") == "ft758m-forced_coord"
    assert zoo_module.best_shipped("generated_003") == "cec_teacher"
    choice.write_text("forced_coord: ft758m-forced_coord\n")
    assert zoo_module.best_shipped("generated_003") == "cec"


def test_a_malformed_partner_choice_is_refused_naming_the_file(tmp_path: Path, monkeypatch) -> None:
    bad = tmp_path / "best.yaml"
    bad.write_text("- forced_coord\n")
    monkeypatch.setattr(zoo_module, "SHIPPED_BEST", bad)
    with pytest.raises(ConfigError, match="best.yaml: expected a mapping of level name"):
        zoo_module.best_shipped("forced_coord")
