"""`cec humans bc --from-play`: a human proxy cloned from `cec play` records (real records of participants
who played a tiny study in process), and the compact state's inverse it reads them with."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import jax
import numpy as np
import pytest
import yaml

from apps.cli import main
from apps.humans import play_proxy
from cec.agents.policy import load_policies
from cec.agents.zoo import load_zoo
from cec.config import from_dict
from cec.envs import overcooked as oc
from cec.humans.bc import BCConfig
from cec.levels.classic import classic_level
from services.play.config import StudyConfig
from services.play.export import finished_rounds
from services.play.game import Round, RoundSetup, compact_state, expand_state, load_partner, pot_cells
from services.play.human_samples import human_samples, read_play_records
from services.play.recording import FileStore
from tests.services.test_play import ROOT, _play_study, _study_dict


@pytest.fixture(scope="module")
def pools() -> dict[str, Any]:
    config = from_dict(StudyConfig, _study_dict())
    return {p.name: load_partner(p, ROOT) for p in config.partners}


@pytest.fixture(scope="module")
def records(tmp_path_factory: pytest.TempPathFactory, pools: dict[str, Any]) -> Path:
    """Two participants through the whole tiny study (practice, 4 rounds, one aborted attempt): the
    study's records folder."""
    root = tmp_path_factory.mktemp("play")
    for _ in range(2):
        _play_study(root, pools)
    return root / "unit"


def _human_steps(folder: Path) -> list[dict[str, Any]]:
    store = FileStore(folder.parent, folder.name, create=False)
    return [s for p in store.participants() for r in finished_rounds(p, store.events(p)) for s in r.steps]


def test_expand_state_inverts_compact_state(pools: dict[str, Any]) -> None:
    level = classic_level("counter_circuit")
    config = from_dict(StudyConfig, _study_dict())
    rnd = Round(RoundSetup(pools["a"].policies[0], "counter_circuit", level, 1, 30, "turn_based", 2), config)
    start, _ = rnd.start()
    compacts = [start] + [rnd.step(a, with_branches=False).state for a in [5, 3, 5, 2, 5, 0, 5, 1] * 3]
    pots = pot_cells(level)
    for c in compacts:
        assert compact_state(expand_state(c, level), pots) == c
    # an env state, through the compact form and back, is the same state (episode 0)
    params = oc.EnvParams(max_steps=30)
    _, state = oc.reset(jax.random.PRNGKey(3), level, params)
    for a in [(3, 5), (5, 2), (0, 5), (5, 5)] * 4:
        state = oc.step(jax.random.PRNGKey(0), state, jax.numpy.array(a, jax.numpy.int32), params).state
        host = jax.device_get(state)
        back = expand_state(compact_state(host, pots), level)
        for mine, theirs in zip(jax.tree.leaves(back), jax.tree.leaves(host), strict=True):
            np.testing.assert_array_equal(mine, theirs)
            assert np.asarray(mine).dtype == np.asarray(theirs).dtype
    for bad, message in [
        ({**start, "pos": [[0, 0]]}, "pos"),
        ({**start, "inv": [0, 7]}, "inv"),
        ({**start, "items": [[1, 1, 0]]}, "item"),
        ({**start, "pots": []}, "pot cells"),
        ({**start, "pots": [[0, 0, 23], *start["pots"]]}, "pot"),
        ({k: v for k, v in start.items() if k != "dir"}, "not a compact state"),
    ]:
        with pytest.raises(ValueError, match=message):
            expand_state(bad, level)


def test_a_proxy_is_cloned_from_play_records(records: Path, tmp_path: Path, capsys: Any) -> None:
    out = tmp_path / "proxies"
    assert main(["humans", "bc", "--from-play", str(records), "--out", str(out), "--epochs", "2"]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out / 'zoo.yaml'}" in printed and "play_unit" in printed
    (raw,) = yaml.safe_load((out / "zoo.yaml").read_text())["policies"]
    assert raw["name"] == "play_unit" and raw["algorithm"] == "human_proxy" and "levels" not in raw
    policies, skipped = load_policies(load_zoo(out / "zoo.yaml"))
    assert not skipped and [(p.name, p.algorithm) for p in policies] == [("play_unit", "human_proxy")]
    f = json.loads((out / "bc.json").read_text())["proxies"]["play_unit"]
    steps = _human_steps(records)
    assert len(steps) == 2 * (3 + 4 * 4)  # practice included, the aborted attempt left out
    assert f["samples"] + f["early_stop_samples"] == len(steps)
    assert f["split"] == "participants" and f["samples"] == f["early_stop_samples"] == 19
    assert len(set(f["fit_participants"]) | set(f["early_stop_participants"])) == 2
    assert f["levels"] == ["coord_ring", "cramped_room"] and len(f["history"]) == 2

    # the samples: the human seat's observation of the state before each step and the human's action
    recs = read_play_records(records)
    participants = sorted(recs.rounds)
    rounds = [r for p in participants for r in recs.rounds[p]]
    samples = human_samples(rounds, participants)
    assert samples.actions.tolist() == [s["human_action"] for s in steps]
    first = rounds[0]  # the practice round; its start state is the env's reset state
    assert first.practice and first.start["state"]["t"] == 0
    params = oc.EnvParams(max_steps=first.start["steps"], random_start_facing=False)
    obs, _ = oc.reset(jax.random.PRNGKey(0), classic_level(first.start["level"]), params)
    np.testing.assert_array_equal(samples.obs[0], np.asarray(obs[first.start["human_seat"]]))
    assert samples.participant[0] == 0 and samples.participant[-1] == 1


def test_one_participant_is_split_by_rounds(tmp_path: Path, pools: dict[str, Any]) -> None:
    _play_study(tmp_path, pools)
    log = io.StringIO()
    manifest = play_proxy(tmp_path / "unit", tmp_path / "out", config=BCConfig(epochs=1), log=log)
    assert "split by rounds instead of participants" in log.getvalue()
    f = json.loads((manifest.parent / "bc.json").read_text())["proxies"]["play_unit"]
    assert f["split"] == "rounds" and (f["samples"], f["early_stop_samples"]) == (3 + 4 + 4, 4 + 4)
    assert f["trained_on"] == "3 rounds" and f["early_stopped_on"] == "2 rounds"


def test_bad_records_are_refused(records: Path, tmp_path: Path, capsys: Any) -> None:
    def refused(folder: Path) -> str:
        assert main(["humans", "bc", "--from-play", str(folder), "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err
        assert err.startswith(("cec humans bc: error: ", "cec humans bc: config error: "))
        return err

    (tmp_path / "empty").mkdir()
    assert "holds no participant records" in refused(tmp_path / "empty")
    assert "is not a folder" in refused(tmp_path / "nowhere")
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    pid = sorted(p.name for p in records.glob("p*.jsonl"))[0]
    events = (records / pid).read_text().splitlines()
    (unfinished / pid).write_text("\n".join(e for e in events if '"round_end"' not in e) + "\n")
    assert "none of its 1 participant(s) finished a round" in refused(unfinished)
    tampered = tmp_path / "tampered"
    tampered.mkdir()
    lines = [json.loads(e) for e in events]
    step = next(e for e in lines if e["type"] == "step")
    step["human_action"] = (step["human_action"] + 1) % 6
    (tampered / pid).write_text("".join(json.dumps(e) + "\n" for e in lines))
    assert "step 1: human_action" in refused(tampered)
    assert not (tmp_path / "o").exists()
    with pytest.raises(SystemExit) as exit_info:
        main(["humans", "bc", "--from-play", str(records), "--data", "data/humans"])
    assert exit_info.value.code == 2
