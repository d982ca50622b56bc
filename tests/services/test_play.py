"""`cec play` without a browser: study config validation, input validation, the study flow, the game's
precomputed branches and carried LSTM state, records and their export."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cec.config import ConfigError, from_dict
from cec.envs import overcooked as oc
from cec.evaluation.results import COLUMNS
from cec.levels.classic import classic_level
from cec.levels.named import check_level, resolve_level
from cec.training.rollout import policy_step
from services.play.config import PartnerSpec, StudyConfig, load_study
from services.play.export import export_tables, finished_rounds
from services.play.game import (
    Round,
    RoundSetup,
    compact_state,
    compiled,
    load_partner,
    pot_cells,
)
from services.play.recording import PARTICIPANT_ID, FileStore, Recorder, RecordError
from services.play.study import InputError, Study, validate_action, validate_rt

ROOT = Path(__file__).resolve().parents[2]
PID = "p" + "ab" * 10


def _study_dict(**changes: Any) -> dict[str, Any]:
    data: dict[str, Any] = {
        "name": "unit",
        "consent": "Agree?",
        "ask": [{"id": "worker_id", "label": "Worker id", "pattern": "[a-z0-9]{4,8}", "max_length": 8}],
        "levels": ["cramped_room"],
        "partners": [
            {"name": "a", "random_init": True, "init_seed": 0},
            {"name": "b", "random_init": True, "init_seed": 1},
        ],
        "rounds_per_partner": 2,
        "practice": {"partner": "a", "level": "coord_ring", "steps": 3},
        "env": {"max_steps": 4, "random_start_facing": False},
        "agent_actions": "greedy",
    }
    data.update(changes)
    return data


@pytest.fixture(scope="module")
def pools() -> dict[str, Any]:
    config = from_dict(StudyConfig, _study_dict())
    return {p.name: load_partner(p, ROOT) for p in config.partners}


def _study(tmp_path: Path, pools: dict[str, Any], **changes: Any) -> tuple[Study, FileStore]:
    config = from_dict(StudyConfig, _study_dict(**changes))
    store = FileStore(tmp_path, config.name)
    return Study(config, ROOT, pools, Recorder([store])), store


# --- configuration ---------------------------------------------------------------------------------------


def test_shipped_studies_load() -> None:
    default, base = load_study(ROOT / "configs/study/default.yaml")
    assert default.levels == ("counter_circuit", "coord_ring") and int(default.env.max_steps) == 200
    assert len(default.survey.items) == 7 and len(default.survey.scale) == 5
    assert default.agent_actions == "greedy" and base == ROOT / "configs/study"
    tiny, _ = load_study(ROOT / "configs/study/tiny.yaml")
    assert tiny.num_rounds == 1 and tiny.practice is not None and tiny.practice.mode == "real_time"


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"colour": "red"}, "unknown key 'colour'"),
        ({"name": "a b"}, "study name"),
        ({"levels": []}, "levels is empty"),
        ({"partners": [{"name": "a"}]}, "exactly one source"),
        ({"partners": [{"name": "a", "random_init": True, "checkpoint": "x"}]}, "exactly one source"),
        ({"partners": [{"name": "a", "random_init": True, "group": "cec"}]}, "`group` selects"),
        ({"partners": [{"name": "a", "random_init": True}, {"name": "a", "random_init": True}]}, "unique"),
        ({"practice": {"partner": "zzz"}}, "practice.partner"),
        ({"mode": "fast"}, "mode 'fast'"),
        ({"ticks_per_second": 0}, "ticks_per_second"),
        ({"human_seat": 2}, "human_seat"),
        ({"agent_actions": "best"}, "agent_actions"),
        ({"agent_gives_way_after": -1}, "agent_gives_way_after"),
        ({"env": {"max_steps": 0}}, "max_steps"),
        ({"survey": {"items": [{"id": "x", "text": "a"}, {"id": "x", "text": "b"}]}}, "unique"),
        ({"survey": {"scale": ["only"]}}, "2 to 11"),
        ({"ask": [{"id": "Bad Id", "label": "x"}]}, "ask[].id"),
        ({"ask": [{"id": "x", "label": "x", "pattern": "("}]}, "regular expression"),
        ({"storage": {"dir": "", "redis_url": ""}}, "storage needs"),
    ],
)
def test_bad_study_configs_name_the_problem(changes: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("(", r"\(")):
        from_dict(StudyConfig, _study_dict(**changes))


def test_level_specs(tmp_path: Path) -> None:
    for spec in ("counter_circuit", "generated_007", "generated:12", "generated:random"):
        check_level(spec, tmp_path)
    (tmp_path / "k.txt").write_text("WWPWW\nO0 1O\nW   W\nWBWXW\n")
    check_level("k.txt", tmp_path)
    for bad in ("generated:x", "nowhere", "generated_999"):
        with pytest.raises(ConfigError):
            check_level(bad, tmp_path)
    rng = np.random.default_rng(0)
    name, level = resolve_level("generated:12", tmp_path, rng)
    assert name == "generated:12" and np.array_equal(
        level.grid, resolve_level("generated:12", tmp_path, rng)[1].grid
    )
    drawn, _ = resolve_level("generated:random", tmp_path, rng)
    assert drawn.startswith("generated:") and drawn != "generated:random"
    assert resolve_level("k.txt", tmp_path, rng)[0] == "k"


# --- input validation ------------------------------------------------------------------------------------


def test_actions_and_reaction_times_are_validated() -> None:
    assert [validate_action(a) for a in range(6)] == list(range(6))
    for bad in (-1, 6, True, 2.0, "1", None):
        with pytest.raises(InputError):
            validate_action(bad)
    assert validate_rt(None) is None and validate_rt(12.3456) == 12.346 and validate_rt(0) == 0.0
    for bad in (float("nan"), float("inf"), -1, "5", True, 3_600_001):
        with pytest.raises(InputError):
            validate_rt(bad)


def test_the_study_flow_validates_every_form(tmp_path: Path, pools: dict[str, Any]) -> None:
    study, store = _study(tmp_path, pools)
    token, p = study.join()
    assert PARTICIPANT_ID.match(p.id) and study.participant(token) is p and study.participant("nope") is None
    assert study.view(p)["stage"] == "consent"
    with pytest.raises(InputError, match="stage 'consent'"):
        study.submit(p, {"stage": "info"})
    with pytest.raises(InputError, match="accept"):
        study.submit(p, {"stage": "consent", "accept": "yes"})
    assert study.submit(p, {"stage": "consent", "accept": True})["stage"] == "info"
    for fields, message in [
        (None, "exactly the keys"),
        ({"worker_id": "abcd", "age": "30"}, "exactly the keys"),
        ({"worker_id": 1234}, "expected text"),
        ({"worker_id": "abcdefghijk"}, "at most 8"),
        ({"worker_id": "AB!"}, "expected format"),
        ({"worker_id": "  "}, "please answer"),
    ]:
        with pytest.raises(InputError, match=message):
            study.submit(p, {"stage": "info", "fields": fields})
    assert study.submit(p, {"stage": "info", "fields": {"worker_id": " ab12 "}})["stage"] == "instructions"
    view = study.submit(p, {"stage": "instructions"})
    assert view["stage"] == "round" and view["practice"] and "partner" not in view
    with pytest.raises(InputError, match="takes no form"):
        study.submit(p, {"stage": "round"})
    events = store.events(p.id)
    assert [e["type"] for e in events] == ["participant", "consent", "info", "instructions"]
    assert events[2]["fields"] == {"worker_id": "ab12"}  # only what the study asks, stripped
    assert (
        token not in (tmp_path / "unit" / f"{p.id}.jsonl").read_text()
    )  # the session token is never recorded


def test_declining_consent_ends_the_study(tmp_path: Path, pools: dict[str, Any]) -> None:
    study, store = _study(tmp_path, pools)
    _, p = study.join()
    assert study.submit(p, {"stage": "consent", "accept": False})["stage"] == "declined"
    last = store.events(p.id)[-1]
    assert last["type"] == "consent" and last["accepted"] is False


def test_round_plans_are_balanced_shuffled_and_reproducible(tmp_path: Path, pools: dict[str, Any]) -> None:
    study, _ = _study(tmp_path, pools, levels=["cramped_room", "coord_ring"], human_seat=-1)
    plans = [study.join()[1] for _ in range(8)]
    for p in plans:
        names = [r.partner for r in p.rounds]
        assert p.rounds[0].practice and sorted(names[1:]) == ["a", "a", "b", "b"]
        kinds = [k for k, _ in p.stages]
        assert kinds == ["consent", "info", "instructions", "round"] + ["round", "survey"] * 4 + ["done"]
    assert [p.level_spec for p in plans] == ["cramped_room", "coord_ring"] * 4
    assert len({tuple(r.partner for r in p.rounds) for p in plans}) > 1  # orders differ between participants
    assert {r.human_seat for p in plans for r in p.rounds} == {0, 1}
    again, _ = _study(tmp_path / "again", pools, levels=["cramped_room", "coord_ring"], human_seat=-1)
    assert [again.join()[1].rounds for _ in range(8)] == [p.rounds for p in plans]
    assert len({p.id for p in plans}) == 8


# --- the game --------------------------------------------------------------------------------------------


def _round(pools: dict[str, Any], seat: int, steps: int = 6, level: str = "coord_ring") -> Round:
    config = from_dict(StudyConfig, _study_dict())
    setup = RoundSetup(pools["a"].policies[0], level, classic_level(level), seat, steps, "turn_based", 3)
    return Round(setup, config)


_env_step = jax.jit(lambda state, actions, params: oc.step(jax.random.PRNGKey(0), state, actions, params))
_all_steps = jax.jit(jax.vmap(_env_step, in_axes=(None, 0, None)))
_agent_step = jax.jit(policy_step, static_argnums=0)


@pytest.mark.parametrize("seat", [0, 1])
def test_branches_are_the_env_steps_and_the_agent_carries_its_lstm(pools: dict[str, Any], seat: int) -> None:
    rnd = _round(pools, seat)
    start, branches = rnd.start()
    params = oc.EnvParams(max_steps=6, random_start_facing=False)
    obs, state = oc.reset(jax.random.PRNGKey(0), classic_level("coord_ring"), params)
    pots = pot_cells(classic_level("coord_ring"))
    assert start == compact_state(jax.device_get(state), pots)
    policy = pools["a"].policies[0]
    network = compiled(policy.network, True).network
    lstm = network.initial_carry((1, 2))
    history = jnp.zeros((1, 2, 0), jnp.int32)
    first = jnp.ones(1, bool)
    humans = [2, 5, 1, 3, 5, 0]
    agent_seat = 1 - seat
    for t, human in enumerate(humans):
        # The agent's action from rollout.policy_step on the same observations, its carry continued.
        lstm, logits, _ = _agent_step(network, policy.params, lstm, obs[None], first, history)
        expected_agent = int(jnp.argmax(logits[0, agent_seat]))
        result = rnd.step(human, with_branches=True)
        assert result.actions[seat] == human and result.actions[agent_seat] == expected_agent
        joints = np.tile(np.array(result.actions), (6, 1))
        joints[:, seat] = np.arange(6)
        wanted = jax.device_get(_all_steps(state, jnp.asarray(joints, jnp.int32), params).state)
        # every precomputed branch is the env's step with that human action
        assert branches == [compact_state(wanted, pots, a) for a in range(6)]
        out = _env_step(state, jnp.array(result.actions, jnp.int32), params)
        assert result.state == compact_state(jax.device_get(out.state), pots)
        assert result.reward == float(out.reward) and result.collision == bool(out.collision)
        assert result.done == (t == len(humans) - 1) and (result.branches is None) == result.done
        obs, state, first = out.obs, out.state, jnp.zeros(1, bool)
        branches = result.branches or []
    with pytest.raises(RuntimeError):
        rnd.step(4, with_branches=True)


# The agent (seat 1, east) and the person (seat 0) face each other in a corridor; the agent's only free
# cell is east of it, (1, 4).
PASSAGE = "WWWPWWW\nO 01  W\nWBWW XW\nWWWWWWW\n"


@pytest.mark.parametrize("give_way_after", [0, 3])
def test_the_agent_steps_aside_after_that_many_collisions_in_a_row(
    pools: dict[str, Any], tmp_path: Path, give_way_after: int
) -> None:
    """An agent that always walks west, into a person who always walks east: every step a collision, unless
    the agent gives way; then it steps onto its free cell (the one move its policy likes least) once the
    collisions reached `agent_gives_way_after`, and walks west again after."""
    (tmp_path / "passage.txt").write_text(PASSAGE)
    name, level = resolve_level(str(tmp_path / "passage.txt"), tmp_path)
    policy = pools["a"].policies[0]
    layers = policy.params["params"]
    bias = jnp.full(6, -5.0).at[3].set(5.0).at[2].set(-9.0)  # west; east least of all
    params = {"params": {**layers, "actor_out": {"kernel": 0 * layers["actor_out"]["kernel"], "bias": bias}}}
    config = from_dict(StudyConfig, _study_dict(agent_gives_way_after=give_way_after))
    setup = RoundSetup(dataclasses.replace(policy, params=params), name, level, 0, 8, "turn_based", 0)
    rnd = Round(setup, config)
    rnd.start()
    steps = [rnd.step(2, with_branches=False) for _ in range(6)]  # the person walks east
    agent = [s.actions[1] for s in steps]
    assert [s.agent_gave_way for s in steps] == [False, False, False, give_way_after == 3, False, False]
    if give_way_after == 0:
        assert agent == [3] * 6 and all(s.collision for s in steps)
    else:  # bumps 1, 2, 3; then east onto (1, 4) while the person takes (1, 3); then west into it again
        assert agent == [3, 3, 3, 2, 3, 3], agent
        assert [s.collision for s in steps] == [True, True, True, False, True, True]
        assert steps[3].state["pos"] == [[1, 3], [1, 4]], steps[3].state


def test_a_round_rejects_bad_actions(pools: dict[str, Any]) -> None:
    rnd = _round(pools, 0)
    with pytest.raises(RuntimeError, match="not started"):
        rnd.step(4, with_branches=False)
    rnd.start()
    with pytest.raises(ValueError, match="integer in"):
        rnd.step(6, with_branches=False)


# --- records and export ----------------------------------------------------------------------------------


def _play_study(tmp_path: Path, pools: dict[str, Any], **changes: Any) -> tuple[Study, FileStore, Any]:
    """One participant through the whole study (practice, 4 rounds, surveys), in process."""
    study, store = _study(tmp_path, pools, **changes)
    _, p = study.join()
    study.submit(p, {"stage": "consent", "accept": True})
    study.submit(p, {"stage": "info", "fields": {"worker_id": "ab12"}})
    study.submit(p, {"stage": "instructions"})
    rng = np.random.default_rng(1)
    aborted = False
    while p.current[0] != "done":
        kind, index = p.current
        if kind == "round":
            rnd, start = study.begin_round(p)
            assert start["type"] == "start" and len(start["branches"]) == 6
            if index == 0 and not aborted:  # a dropped connection: the round is played again from the start
                study.step(p, rnd, 1, 100.0)
                study.abort_round(p, rnd)
                with pytest.raises(InputError, match="no longer running"):
                    study.step(p, rnd, 1, 100.0)
                aborted = True
                continue
            while not rnd.done:
                study.step(p, rnd, int(rng.integers(6)), float(rng.uniform(50, 500)))
        else:
            with pytest.raises(InputError, match="every statement"):
                study.submit(p, {"stage": "survey", "round": index, "answers": {"adapted": 3}})
            answers = {item.id: 1 + (index + k) % 5 for k, item in enumerate(study.config.survey.items)}
            with pytest.raises(InputError, match="from 1 to 5"):
                study.submit(p, {"stage": "survey", "round": index, "answers": {**answers, "adapted": 6}})
            with pytest.raises(InputError, match="about round"):
                study.submit(p, {"stage": "survey", "round": index + 1, "answers": answers})
            study.submit(p, {"stage": "survey", "round": index, "answers": answers})
    return study, store, p


@pytest.mark.parametrize("gives_way", [0, 2])
def test_records_hold_every_step_and_export_to_the_result_table(
    tmp_path: Path, pools: dict[str, Any], gives_way: int
) -> None:
    study, store, p = _play_study(tmp_path, pools, agent_gives_way_after=gives_way)
    events = store.events(p.id)
    assert events[-1]["type"] == "complete" and events[-1]["code"] == p.code
    assert sum(e["type"] == "round_abort" for e in events) == 1
    rounds = finished_rounds(p.id, events)
    assert [r.round for r in rounds] == [-1, 0, 1, 2, 3]
    assert [len(r.steps) for r in rounds] == [3, 4, 4, 4, 4]
    for r in rounds:
        assert r.steps[-1]["done"] and not any(s["done"] for s in r.steps[:-1])
        assert all(s["rt_ms"] is not None and len(s["actions"]) == 2 for s in r.steps)
    table, survey = export_tables(store)
    assert len(table) == 4  # the practice round is not exported
    assert set(table.algorithm_a) == {"human"} and set(table.policy_a) == {p.id}
    assert sorted(table.policy_b) == ["a", "a", "b", "b"] and list(table.episode) == [0, 1, 2, 3]
    for i, r in enumerate(rounds[1:]):
        assert table.returns[i] == r.end["return"] and table.collisions[i] == r.end["collisions"]
        assert table.episode_steps[i] == 4 and table.seat[i] == r.start["human_seat"]
    # a study whose agent gave way says so in every row: its results are not those of the plain policy
    expected = "greedy; gives way after 2 collisions" if gives_way else "greedy"
    assert set(table.actions) == {expected}
    assert len(survey) == 4 * 7 and {row["partner"] for row in survey} == {"a", "b"}
    assert set(COLUMNS) >= {"collisions", "episode_steps"}


def test_inconsistent_or_cut_records_are_caught(tmp_path: Path) -> None:
    start: dict[str, Any] = {
        "type": "round_start", "round": 0, "attempt": 0, "practice": False, "partner": "a", "policy": "a",
        "algorithm": "cec", "seed": 0, "level": "coord_ring", "level_ascii": "", "human_seat": 0,
        "steps": 2, "agent_actions": "greedy", "state": {},
    }  # fmt: skip
    step: dict[str, Any] = {
        "type": "step", "round": 0, "attempt": 0, "actions": [0, 0], "human_action": 0, "reward": 20.0,
        "collision": True, "done": False, "state": {},
    }  # fmt: skip
    end: dict[str, Any] = {
        "type": "round_end", "round": 0, "attempt": 0, "steps": 2, "return": 40.0, "shaped_return": 0.0,
        "collisions": 2, "deliveries": 2,
    }  # fmt: skip
    good = [start, {**step, "t": 1}, {**step, "t": 2}, end]
    assert len(finished_rounds(PID, good)) == 1
    with pytest.raises(RecordError, match="step numbers"):
        finished_rounds(PID, [start, {**step, "t": 1}, {**step, "t": 3}, end])
    with pytest.raises(RecordError, match="counts 2 steps"):
        finished_rounds(PID, [start, {**step, "t": 1}, end])
    with pytest.raises(RecordError, match="differ"):
        finished_rounds(PID, [start, {**step, "t": 1}, {**step, "t": 2}, {**end, "return": 20.0}])
    problems: list[str] = []  # given a list, an inconsistent round is left out and named there
    assert finished_rounds(PID, [start, {**step, "t": 1}, end, *good], problems) == finished_rounds(PID, good)
    assert len(problems) == 1 and "counts 2 steps" in problems[0]
    aborted: list[dict[str, Any]] = [start, {**step, "t": 1}, {"type": "round_abort"}]
    assert finished_rounds(PID, aborted + good) == finished_rounds(PID, good)

    store = FileStore(tmp_path, "s")
    for ev in good:
        store.append(PID, ev)
    store.close()
    path = store.path(PID)
    path.write_text(path.read_text() + '{"type": "st')  # a crash while the last event was written
    assert store.events(PID) == good
    assert "line 5" in str(store.quarantined[-1]) and "cut off" in str(store.quarantined[-1])
    store.append(PID, {"type": "round_abort", "round": 1, "attempt": 0, "steps": -1})  # after a restart
    assert store.events(PID) == [*good, {"type": "round_abort", "round": 1, "attempt": 0, "steps": -1}]
    path.write_text('{"oops\n' + path.read_text())  # a damaged line: quarantined, the rest read
    assert store.events(PID)[:4] == good
    assert any(str(path) in q.where and "line 1" in q.where for q in store.quarantined)
    with pytest.raises(ValueError, match="participant id"):
        store.append("../etc", {})
    with pytest.raises(RecordError, match="no records"):
        store.events("p" + "0" * 20)
    assert json.loads(path.read_text().splitlines()[1])["type"] == "round_start"


def test_a_restarted_server_takes_its_participants_back(tmp_path: Path, pools: dict[str, Any]) -> None:
    study, store = _study(tmp_path, pools)
    token, p = study.join()
    study.submit(p, {"stage": "consent", "accept": True})
    study.submit(p, {"stage": "info", "fields": {"worker_id": "ab12"}})
    study.submit(p, {"stage": "instructions"})
    rnd, _ = study.begin_round(p)
    while not rnd.done:  # the practice round
        study.step(p, rnd, 4, None)
    rnd, _ = study.begin_round(p)
    study.step(p, rnd, 2, 80.0)  # ... and the server stops during round 0
    other_token, _ = study.join()
    store.close()

    again, store2 = _study(tmp_path, pools)
    records = {pid: store2.events(pid) for pid in store2.participants()}
    assert again.restore(records) == 2
    q = again.participant(token)
    assert q is not None and q.id == p.id and q.current == ("round", 0) and q.code == p.code
    assert q.rounds == p.rounds and q.attempts == {-1: 1, 0: 1}
    assert again.participant(other_token) is not None and again.participant("forged") is None
    assert store2.events(p.id)[-1]["type"] == "round_abort"  # the interrupted round, closed in the log
    rnd, start = again.begin_round(q)
    assert start["round"] == 0 and store2.events(p.id)[-1]["attempt"] == 1
    _, newcomer = again.join()
    assert newcomer.index == 2  # arrival indices continue after the restored ones

    changed, store3 = _study(tmp_path, pools, rounds_per_partner=1)  # another study design: no resuming
    assert changed.restore({pid: store3.events(pid) for pid in store3.participants()}) == 0
    assert changed.participant(token) is None


def test_partners_load_from_checkpoints_and_zoo_groups(saved_run: Any, tmp_path: Path) -> None:
    """A real two-seed checkpoint (written by the trainer's checkpoint code) as a partner, directly and as
    a zoo group; single-task entries are drawn only for their own kitchen."""
    run_dir, ckpt, state = saved_run
    pool = load_partner(PartnerSpec("ippo5", checkpoint=run_dir.name, seed=5), run_dir.parent)  # relative
    (policy,) = pool.policies
    assert policy.algorithm == "ippo" and policy.seed == 5 and pool.eligible("coord_ring") == [0]
    for mine, saved in zip(jax.tree.leaves(policy.params), jax.tree.leaves(state.params), strict=True):
        np.testing.assert_array_equal(mine, np.asarray(saved)[1])
    with pytest.raises(ConfigError, match="partner 'two'.*seeds"):
        load_partner(PartnerSpec("two", checkpoint=str(ckpt)), tmp_path)
    with pytest.raises(ConfigError, match="partner 'gone'"):
        load_partner(PartnerSpec("gone", checkpoint="no/such/run"), tmp_path)

    (tmp_path / "zoo.yaml").write_text(
        "policies:\n"
        f"  - {{name: ippo_cr_s4, seed: 4, checkpoint: {ckpt}, levels: [cramped_room]}}\n"
        f"  - {{name: ippo_cr_s5, seed: 5, checkpoint: {ckpt}, levels: [cramped_room]}}\n"
        f"  - {{name: fcp_s4, algorithm: fcp, seed: 4, checkpoint: {ckpt}}}\n"
    )
    group = load_partner(PartnerSpec("ippo", zoo="zoo.yaml", group="ippo"), tmp_path)
    assert [p.name for p in group.policies] == ["ippo_cr_s4", "ippo_cr_s5"]
    assert group.eligible("cramped_room") == [0, 1] and group.eligible("coord_ring") == []
    with pytest.raises(
        ConfigError, match=r"no loadable entry of group 'cec' \(groups there: \['fcp', 'ippo'\]"
    ):
        load_partner(PartnerSpec("cec", zoo="zoo.yaml", group="cec"), tmp_path)

    # A study round with the checkpoint's agent (greedy), on its kitchen.
    study = from_dict(StudyConfig, _study_dict())
    rnd = Round(
        RoundSetup(policy, "cramped_room", classic_level("cramped_room"), 1, 3, "turn_based", 0), study
    )
    rnd.start()
    results = [rnd.step(a, with_branches=True) for a in (4, 5, 2)]
    assert results[-1].done and [r.actions[1] for r in results] == [4, 5, 2]
