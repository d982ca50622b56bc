"""Free play as a game (`StudyConfig.free_play`, services/play/free_play.py), in process: rounds without end,
the partner of each the person's choice (the same or the next), a summary of the rounds so far, a dropped
round played afresh, a restarted server that rebuilds the plan from the records; and the records folder of
`cec play serve`'s flags, one per set of flags."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import pytest

from cec.config import ConfigError, from_dict
from services.play.config import StudyConfig
from services.play.export import finished_rounds
from services.play.game import load_partner
from services.play.main import FREE_PLAY_DIR, free_play_config
from services.play.recording import FileStore, Recorder, check_event
from services.play.study import InputError, Participant, Study

ROOT = Path(__file__).resolve().parents[2]


def _config(**changes: Any) -> StudyConfig:
    data: dict[str, Any] = {
        "name": "free",
        "levels": ["cramped_room"],
        "partners": [
            {"name": "a", "random_init": True, "init_seed": 0},
            {"name": "b", "random_init": True, "init_seed": 1},
        ],
        "env": {"max_steps": 3, "random_start_facing": False},
        "survey": {"items": []},
        "free_play": True,
    }
    data.update(changes)
    return from_dict(StudyConfig, data)


@pytest.fixture(scope="module")
def pools() -> dict[str, Any]:
    return {p.name: load_partner(p, ROOT) for p in _config().partners}


def _study(tmp_path: Path, pools: dict[str, Any]) -> tuple[Study, FileStore]:
    store = FileStore(tmp_path, "free")
    return Study(_config(), ROOT, pools, Recorder([store])), store


def _play(study: Study, p: Participant) -> None:
    rnd, _ = study.begin_round(p)
    while not rnd.done:
        study.step(p, rnd, 4, 10.0)


def test_rounds_go_on_with_the_partner_the_person_chooses(tmp_path: Path, pools: dict[str, Any]) -> None:
    study, store = _study(tmp_path, pools)
    token, p = study.join()
    assert study.view(p)["free_play"] is True
    study.submit(p, {"stage": "instructions"})
    first = study.view(p)
    assert (
        first["stage"] == "round" and first["number"] == 1 and "same" not in first and first["played"] == []
    )
    with pytest.raises(InputError, match="first round's partner is drawn"):
        study.submit(p, {"stage": "round", "round": 0, "partner": "next"})
    _play(study, p)
    second = study.view(p)  # round 1 is planned at once: the page (and a reload) shows a fresh round
    assert second["stage"] == "round" and second["number"] == 2 and second["choice"] == "same"
    assert second["partner"] == first["partner"] == second["same"] and second["next"] != second["same"]
    assert [r["number"] for r in second["played"]] == [1] and second["rounds_played"] == 1
    for bad, match in (
        ({"stage": "round", "round": 1, "partner": "other"}, "one of"),
        ({"stage": "round", "round": 5, "partner": "next"}, "coming round is round 1"),
        ({"stage": "survey", "round": 1}, "at stage 'round'"),
    ):
        with pytest.raises(InputError, match=match):
            study.submit(p, bad)
    assert study.submit(p, {"stage": "round", "round": 1, "partner": "next"})["partner"] == second["next"]
    assert study.submit(p, {"stage": "round", "round": 1, "partner": "next"})["partner"] == second["next"]
    rnd, _ = study.begin_round(p)  # the connection drops mid-round: the round starts afresh
    study.step(p, rnd, 4, 10.0)
    with pytest.raises(InputError, match="being played"):
        study.submit(p, {"stage": "round", "round": 1, "partner": "same"})
    study.abort_round(p, rnd)
    _play(study, p)
    _play(study, p)
    third = study.view(p)
    assert third["number"] == 4 and [r["partner"] for r in third["played"]] == [
        first["partner"]["name"],
        second["next"]["name"],
        second["next"]["name"],
    ]
    events = store.events(p.id)
    assert all(check_event(ev) is None for ev in events)
    assert "complete" not in [ev["type"] for ev in events]  # no completion code in free play
    rounds = finished_rounds(p.id, events)
    assert [r.round for r in rounds] == [0, 1, 2]  # each round recorded once (the dropped one aborted)
    assert [r.start["policy"] for r in rounds] == [r["partner"] for r in third["played"]]

    # a restarted server takes the person back at round 3, with the plan and summary rebuilt
    store.close()
    again, store2 = _study(tmp_path, pools)
    assert again.restore({pid: store2.events(pid) for pid in store2.participants()}) == 1
    q = again.participant(token)
    assert q is not None and q.rounds == p.rounds and again.view(q) == {**third, "stage": "round"}


def test_free_play_takes_no_survey_or_practice() -> None:
    with pytest.raises(ConfigError, match="without a survey or a practice round"):
        _config(survey={"items": [{"id": "fun", "text": "Fun."}]})
    with pytest.raises(ConfigError, match="without a survey or a practice round"):
        _config(practice={"level": "cramped_room", "steps": 3})


def _flags(**changes: Any) -> argparse.Namespace:
    flags: dict[str, Any] = dict(
        partner="cec", checkpoint=None, seed=None, zoo=None, group="", random_init=False,
        level="cramped_room", mode="turn_based", agent_actions="sampled", give_way_after=3, steps=200,
        data=None, redis_url=None,
    )  # fmt: skip
    flags.update(changes)
    return argparse.Namespace(**flags)


def test_each_set_of_flags_records_to_a_folder_of_its_own_under_runs() -> None:
    config = free_play_config(_flags())
    assert config.free_play and config.storage.dir == FREE_PLAY_DIR == "runs/play"
    assert config.name.startswith("free_play-cec-cramped_room-")
    names = {
        free_play_config(_flags(**change)).name
        for change in ({}, {"level": "coord_ring"}, {"steps": 100}, {"mode": "real_time"}, {"partner": None,
                       "random_init": True}, {"give_way_after": 0})
    }  # fmt: skip
    assert len(names) == 6
    assert config.agent_gives_way_after == 3
    assert free_play_config(_flags(give_way_after=0)).agent_gives_way_after == 0
    assert free_play_config(_flags(data="elsewhere")).storage.dir == "elsewhere"


def test_the_page_and_the_help_name_a_partner_that_learned_from_the_scripted_cook(
    tmp_path: Path, pools: dict[str, Any]
) -> None:
    """DESIGN rule 16: the kickstarted partners are named for what they are where a person meets them."""
    from services.play import free_play
    from services.play.main import add_arguments

    words = "CEC with a scripted teacher (imitates a hand-written cook; not the paper's method)"
    assert free_play.note("cec_teacher") == words
    assert free_play.note("cec_finetune_teacher").startswith(words)
    assert free_play.note("cec") == free_play.note("random_init") == ""
    study, _ = _study(tmp_path, pools)
    _, p = study.join()
    study.submit(p, {"stage": "instructions"})
    assert study.view(p)["partner_note"] == ""  # an untrained partner: nothing borrowed
    play = argparse.ArgumentParser(prog="cec play")
    add_arguments(play)
    serve = next(a for a in play._subparsers._group_actions if a.dest == "play_command").choices["serve"]
    text = " ".join(serve.format_help().split())
    assert "cec_teacher" in text and words in text
