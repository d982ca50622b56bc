"""The level server's wire format and pure logic: codec, request configs, replay sampler, stub freshness."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from cec.config import ConfigError
from cec.levels import LevelError, stack_levels, validate_level
from cec.levels.classic import classic_levels
from cec.levels.generator import GeneratorConfig, generate_batch
from cec.levels.heldout import heldout_batch
from cec.levels.level import Level
from cec.levels.v1 import level_service_pb2 as pb
from cec.levels.wire import (
    BYTES_PER_LEVEL,
    WireError,
    config_from_proto,
    config_to_proto,
    decode,
    encode,
    invalid_rows,
    reject_unknown_fields,
)
from services.level_server.config import CurriculumConfig, LevelServerConfig
from services.level_server.curriculum import PrioritizedLevelReplay

ROOT = Path(__file__).resolve().parents[3]


def test_generated_stubs_are_fresh():
    out = subprocess.run([sys.executable, "scripts/gen_proto.py", "--check"], cwd=ROOT, capture_output=True,
                         text=True)  # fmt: skip
    assert out.returncode == 0, out.stderr


def test_round_trip_is_exact_and_compact():
    levels = heldout_batch()
    msg = encode(levels, first_index=7, names=[str(i) for i in range(105)])
    back = decode(pb.LevelBatch.FromString(msg.SerializeToString()))
    for a, b in zip(jax.tree.leaves(levels), jax.tree.leaves(back), strict=True):
        np.testing.assert_array_equal(np.asarray(a), b)
    assert msg.first_index == 7 and msg.names[3] == "3"
    assert len(msg.grid) + len(msg.agent_pos) + len(msg.agent_dir) + len(msg.size) == 105 * BYTES_PER_LEVEL
    assert BYTES_PER_LEVEL == 89


def _corrupt(levels: Level, i: int, field: str, value) -> Level:
    arr = np.array(getattr(levels, field))
    arr[i] = value
    return levels.replace(**{field: arr})


def test_vectorised_check_agrees_with_validate_level():
    good = jax.device_get(generate_batch(jax.random.PRNGKey(0), 16))
    assert invalid_rows(good).size == 0
    wall = np.array(good.grid[3])
    wall[tuple(np.asarray(good.agent_pos[3, 0]))] = 1  # agent 0 now stands on a counter
    cases = {
        3: _corrupt(good, 3, "grid", wall),
        5: _corrupt(good, 5, "agent_dir", [0, 7]),
        6: _corrupt(good, 6, "size", [0, 5]),
        9: _corrupt(good, 9, "agent_pos", np.asarray(good.agent_pos[9, [0, 0]])),
    }
    for i, bad in cases.items():
        assert invalid_rows(bad).tolist() == [i]
        with pytest.raises(LevelError):
            validate_level(jax.tree.map(lambda x, i=i: np.asarray(x)[i], bad))
        with pytest.raises(WireError, match=f"level {i}"):
            decode(encode(bad))


def test_truncated_fields_are_wire_errors():
    msg = encode(stack_levels(list(classic_levels().values())))
    msg.size = msg.size[:-1]
    with pytest.raises(WireError, match="size"):
        decode(msg)


#: A value other than the default for every `GeneratorConfig` field, as a client would send it. A field added
#: to the config later has no entry here, and the test below fails until the wire carries it (or refuses it).
NON_DEFAULT = {
    "structures": ("coord_ring", "forced_coord", "counter_circuit"),
    "onion_piles": (2, 3),
    "plate_piles": (1, 2),
    "pots": (2, 4),
    "goals": (1, 3),
    "count_decay": 0.9,
    "allow_decoys": True,
    "exclude_heldout": False,
    "handover_share": 0.35,
    "structure_weights": (1.0, 2.0, 3.0),
}
#: Fields a level server cannot honour, and so refuses by name: it never streams the evaluation set.
REFUSED = {"exclude_heldout"}


def test_every_generator_field_crosses_the_wire_or_is_refused_by_name():
    fields = {f.name for f in dataclasses.fields(GeneratorConfig)}
    assert fields == set(NON_DEFAULT), (
        f"GeneratorConfig fields without a wire test: {sorted(fields - set(NON_DEFAULT))}; carry each in "
        "proto/cec/levels/v1/level_service.proto and cec.levels.wire, then give it a non-default value here"
    )
    defaults = GeneratorConfig()
    carried = {k: v for k, v in NON_DEFAULT.items() if k not in REFUSED}
    custom = defaults.replace(**carried)
    for name, value in carried.items():
        assert getattr(defaults, name) != value, f"{name}: the test's value must differ from the default"
    # every carried field survives the trip through serialised bytes, each on its own and all together
    for changes in [{k: v} for k, v in carried.items() if k != "structure_weights"] + [carried]:
        want = defaults.replace(**changes)
        wire = pb.GeneratorConfig.FromString(config_to_proto(want).SerializeToString())
        assert config_from_proto(wire, defaults) == want, changes
    assert config_from_proto(config_to_proto(custom), defaults) == custom
    for name in REFUSED:
        with pytest.raises(ConfigError, match=name):
            config_to_proto(defaults.replace(**{name: NON_DEFAULT[name]}))


def test_config_round_trip_and_defaults():
    defaults = GeneratorConfig()
    custom = GeneratorConfig(structures=("coord_ring",), pots=(2, 3), count_decay=0.9, allow_decoys=True)
    assert config_from_proto(config_to_proto(custom), defaults) == custom
    assert config_from_proto(pb.GeneratorConfig(), defaults) == defaults
    assert config_from_proto(pb.GeneratorConfig(goals=pb.Bounds(min=1, max=2)), defaults).goals == (1, 2)
    for bad in (pb.GeneratorConfig(structures=["nope"]), pb.GeneratorConfig(pots=pb.Bounds(min=0, max=2)),
                pb.GeneratorConfig(onion_piles=pb.Bounds(min=1, max=10**9))):  # fmt: skip
        with pytest.raises(ConfigError):
            config_from_proto(bad, defaults)


def test_unknown_fields_are_rejected_at_any_depth():
    ok = pb.StreamLevelsRequest(seed=1, config=pb.GeneratorConfig(pots=pb.Bounds(min=1, max=2)))
    reject_unknown_fields(ok)
    nested = pb.StreamLevelsRequest.FromString(ok.SerializeToString() + b"\x2a\x02\x78\x01")
    with pytest.raises(WireError, match="config"):
        reject_unknown_fields(nested)


def test_replay_prefers_high_scores_and_keeps_the_best_at_capacity():
    levels = jax.device_get(generate_batch(jax.random.PRNGKey(1), 6))
    plr = PrioritizedLevelReplay(CurriculumConfig(enabled=True, capacity=4, min_fill=2, staleness_coef=0.0))
    assert plr.update(jax.tree.map(lambda x: x[:4], levels), np.array([0.1, 3.0, 0.2, 0.3])) == 4
    p = plr.probabilities()
    assert p.argmax() == 1 and np.isclose(p.sum(), 1.0)
    # at capacity: a higher score replaces the lowest (0.1), a lower one is dropped
    assert plr.update(jax.tree.map(lambda x: x[4:], levels), np.array([1.0, 0.05])) == 1 and len(plr) == 4
    sample = plr.sample(2000)
    from cec.levels.fingerprint import fingerprint_host

    fps = [fp.tobytes() for fp in fingerprint_host(sample)]
    top = fingerprint_host(jax.tree.map(lambda x: x[1], levels)).tobytes()
    dropped = fingerprint_host(jax.tree.map(lambda x: x[5], levels)).tobytes()
    assert fps.count(top) > 1000 and dropped not in fps
    # a reported level's score replaces its old one
    plr.update(jax.tree.map(lambda x: x[1:2], levels), np.array([0.0]))
    assert plr.probabilities().argmax() != plr._slot[top]


def test_staleness_revisits_levels_not_sampled_for_long():
    levels = jax.device_get(generate_batch(jax.random.PRNGKey(2), 3))
    plr = PrioritizedLevelReplay(CurriculumConfig(enabled=True, capacity=3, min_fill=1, staleness_coef=1.0))
    plr.update(levels, np.array([5.0, 0.0, 0.0]))
    plr.sample(1)
    p = plr.probabilities()  # pure staleness: levels not just sampled carry the mass
    assert np.isclose(p.sum(), 1.0) and p.max() < 1.0


@pytest.mark.parametrize(
    ("overrides", "words"),
    [
        (["host=0.0.0.0"], "auth_token"),
        (["tls_cert=/nonexistent.pem", "tls_key=/nonexistent.key"], "nonexistent.pem. does not exist"),
        (["tls_cert=x.pem"], "both"),
        (["port=70000"], "port"),
        (["max_batch_size=0"], "max_batch_size"),
        (["curriculum.replay_prob=1.5"], "replay_prob"),
        (["generator.pots=[0, 2]"], "pots"),
        (["max_batch_sise=5"], "max_batch_size"),
        (["generator.exclude_heldout=false"], "exclude_heldout"),
    ],
)
def test_bad_server_configs_name_the_fix(overrides, words):
    from cec.config import load_config

    with pytest.raises(ConfigError, match=words):
        load_config(LevelServerConfig, None, overrides)


def test_config_preset_loads():
    from cec.config import load_config

    cfg = load_config(LevelServerConfig, ROOT / "configs/level_server.yaml", ["port=0"])
    assert cfg.port == 0 and cfg.is_loopback and not cfg.curriculum.enabled
