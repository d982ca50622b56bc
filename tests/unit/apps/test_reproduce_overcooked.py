"""`cec reproduce overcooked`: the plan, the whole pipeline at a tiny budget, the seed-level summary."""

from __future__ import annotations

import dataclasses
import io
import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from apps import humans
from apps.cli import main
from apps.reproduce import overcooked as ro
from apps.zoo_build import export_zoo
from cec.agents.zoo import SkippedEntry
from cec.config import ConfigError, load_config
from cec.evaluation.results import make_table
from cec.humans.bc import BCConfig
from cec.training.config import TrainConfig

TINY_NET = (
    "network_overrides={conv_features: [], encoder_features: [8], lstm_features: 0, actor_features: [8], "
    "critic_features: [8], egocentric: true, cell_features: 2}"
)
TINY = ro.Mode(
    name="tiny",
    preset=ro.QUICK.preset,
    seeds={
        "cec": (200, 201),
        "ippo": (0, 1),
        "fcp": (100, 101),
        "e3t": (150, 151),
        "cec_finetune": (300, 301),
    },
    steps={a: 256 for a in ro.ALGORITHMS},  # 2 updates of 8 envs x 16 steps
    kitchens=("cramped_room",),
    episodes={"classic": 1, "heldout": 1},
    overrides=(
        "num_envs=8",
        "num_steps=16",
        "ppo.num_minibatches=2",
        "ppo.update_epochs=1",
        "updates_per_call=1",
        TINY_NET,
    ),  # fmt: skip
    generated_levels=1,  # as many as the classic kitchens: one compiled evaluation call serves both sets
)


def test_the_plan_trains_every_baseline_per_kitchen_with_the_cec_network(tmp_path: Path) -> None:
    for mode in (ro.QUICK, ro.CPU, ro.PAPER):
        lines = ro.plan_lines(mode, tmp_path / mode.name)
        names = [p.run for p in lines]
        assert names[0] == f"cec-s{mode.seeds['cec'][0]}"
        for k in mode.kitchens:
            for algo in ("ippo", "fcp", "e3t"):
                assert f"{algo}_{k}-s{mode.seeds[algo][0]}" in names
            finetunes = [n for n in names if n.startswith(f"cec_finetune_{k}-")]
            assert len(finetunes) == len(mode.seeds["cec"])  # one per CEC seed
        assert all(p.estimate_s > 0 for p in lines) or mode is ro.PAPER  # not measured on a CPU
    spec = yaml.safe_load((tmp_path / "cpu" / "spec.yaml").read_text())["entries"]
    fcp = next(e for e in spec if e["name"] == "fcp_cramped_room")
    assert "runs/ippo_cramped_room-s0, seeds: [0, 1, 2, 3]" in next(
        o for o in fcp["overrides"] if o.startswith("partner.population")
    )
    assert {e["preset"] for e in spec} == {str(ro.ROOT / ro.CPU.preset)}


def test_seed_scores_average_each_seed_over_its_partners_first() -> None:
    """Seeds are the units: seed 0 paired with two partners is one number, not two samples."""
    pairs = [(0, 1, 40.0), (0, 2, 20.0), (1, 2, 60.0), (0, 0, 80.0), (1, 1, 80.0), (2, 2, 100.0)]
    rows = [("cec", a, "cec", b, seat, r) for a, b, r in pairs for seat in (0, 1)]
    rows.append(("cec", 0, "cook", 0, 0, 20.0))
    n = len(rows)
    columns = {
        "policy_a": [f"{r[0]}{r[1]}" for r in rows], "algorithm_a": [r[0] for r in rows],
        "seed_a": [r[1] for r in rows], "policy_b": [f"{r[2]}{r[3]}" for r in rows],
        "algorithm_b": [r[2] for r in rows], "seed_b": [r[3] for r in rows], "level": ["generated_000"] * n,
        "seat": [r[4] for r in rows], "episode": [0] * n, "returns": [r[5] for r in rows],
        "deliveries": [r[5] / 20 for r in rows], "collisions": [0] * n, "shaped_return": [0.0] * n,
        "env": ["overcooked"] * n, "episode_steps": [400] * n, "actions": [6] * n,
    }  # fmt: skip
    table = make_table(columns)
    scores = ro.seed_scores(table, ["generated_000"])["cec"]
    assert scores.seeds == (0, 1, 2)
    assert scores.xp == (30.0, 50.0, 40.0) and scores.sp == (80.0, 80.0, 100.0)
    assert scores.cook[0] == 20.0 and np.isnan(scores.cook[1])


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_the_pipeline_trains_evaluates_and_reports_then_resumes_from_its_results(tmp_path: Path) -> None:
    # human proxies with the agents' (tiny) network, cloned from the first recorded game of each kitchen
    humans.import_games(tmp_path / "humans", games_per_kitchen=1, log=io.StringIO())
    network = load_config(TrainConfig, str(ro.ROOT / TINY.preset), [TINY_NET]).network_config
    proxies = humans.train_proxies(
        tmp_path / "humans", tmp_path / "proxies", kitchens=["cramped_room"],
        config=BCConfig(epochs=1, network=network), log=io.StringIO(),
    )  # fmt: skip
    mode = dataclasses.replace(TINY, proxies=str(proxies))
    work, out, log = tmp_path / "work", tmp_path / "out", io.StringIO()
    report = ro.reproduce_overcooked(mode, work, out, progress=False, log=log, command="tiny")
    assert report is not None and report.exists()
    text = report.read_text()
    for needle in ("## The 1 classic kitchens", "## The 1 held-out kitchens", "| CEC |", "| IPPO |",
                   "| FCP |", "| E3T |", "| CEC-Finetune |", "130.51 (text)", "≈70 (figure)",
                   "the paper's text gives: CEC-E3T 28.21", "(seeds as units)",
                   "| with human proxies |", "The paper's human study", "| control: untrained CEC network |",
                   "| control: no-op agent |", "## Per kitchen, collisions",
                   "| cramped_room | held-out |"):  # fmt: skip
        assert needle in text, needle
    # the recorded time of each training run and of the cross-play, kept for a report that reuses them
    assert "Recorded times of the work behind these numbers" in text and "not recorded" not in text
    row = re.search(r"\| cec-s200 \| 2 \| 256 \| 2 \| [0-9.]+ min \|", text)
    assert row, text
    summary = json.loads((out / "summary.json").read_text())
    cec = summary["summary"]["heldout"]["cec"]
    assert cec["seeds"] == [200, 201] and len(cec["xp"]) == 2 and len(cec["cook"]) == 2
    assert all(np.isnan(cec["human"]))  # the proxies play their own (classic) kitchen only
    for algo in ro.ALGORITHMS:  # every seed played both proxies on the classic kitchen
        human = summary["summary"]["classic"][algo]["human"]
        assert len(human) == len(TINY.seeds[algo]) and np.all(np.isfinite(human)), algo
    assert "human_proxy" not in summary["summary"]["classic"]  # partners, not an algorithm of the summary
    for control, seeds in ((ro.UNTRAINED, [200, 201]), (ro.NOOP, [0])):  # beside every score with the cook
        for level_set in ro.LEVEL_SETS:
            scores = summary["summary"][level_set][control]
            assert scores["seeds"] == seeds and np.all(np.isfinite(scores["cook"])), (control, level_set)
    assert summary["summary"]["classic"][ro.NOOP]["sp"] == [0.0]  # two agents that stay deliver nothing
    assert (work / "controls" / ro.MACHINE_FILE).is_file()  # where they were played, for a later report
    assert summary["summary"]["heldout"]["ippo"]["seeds"] == [0, 1]  # single-kitchen agents play held-out
    assert (out / "curves_cec.png").exists() and (out / "cec_xp_heldout.gif").exists()
    # a second invocation trains nothing and plays nothing again
    log = io.StringIO()
    ro.reproduce_overcooked(mode, work, out, progress=False, log=log, command="tiny")
    assert log.getvalue().count("not played again") == 2 and "finished, skipping" in log.getvalue()
    # the work folder brought back without its checkpoints (from a GPU machine): the report from its table,
    # the GIF from the exported CEC seeds, the machine that trained and played named
    export_zoo(work / "zoo" / "zoo.yaml", tmp_path / "shipped", names=["cec-s200", "cec-s201"])
    for ckpt in (work / "zoo" / "runs").glob("*/checkpoints"):
        shutil.rmtree(ckpt)
    (out / "cec_xp_heldout.gif").unlink()
    ran_on = json.loads((work / ro.MACHINE_FILE).read_text())
    again = ro.reproduce_overcooked(
        mode, work, tmp_path / "again", log=io.StringIO(), command="tiny", report_only=True,
        policies=tmp_path / "shipped" / "zoo.yaml",
    )  # fmt: skip
    assert (
        again is not None and again.read_text().count("| CEC |") == 4
    )  # 2 level sets, per kitchen, collisions
    assert f"Trained and played on: {ran_on['machine']['device']}" in again.read_text()
    assert row.group(0) in again.read_text()  # its metrics kept the recorded time
    assert (tmp_path / "again" / "cec_xp_heldout.gif").exists()
    with pytest.raises(ConfigError, match="results.csv"):
        ro.reproduce_overcooked(TINY, tmp_path / "empty", out, log=io.StringIO(), report_only=True)


def test_proxies_that_cannot_play_are_named_with_the_reason() -> None:
    summary = {"classic": {"cec": ro.SeedScores((200,), (10.0,), (20.0,), (30.0,), (math.nan,))}}
    skipped = [SkippedEntry("hp_cramped_room", "human_proxy", 0, "its network differs")]
    (line, _) = ro._human_lines(TINY, summary, skipped)
    assert line.endswith("not played (they could not play with the agents: its network differs).")


def test_plan_command_prints_runs_and_time(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["reproduce", "overcooked", "--quick", "--plan", "--work", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "cec-s200" in printed and "ippo_cramped_room-s0" in printed and "training: ~" in printed
    assert "0% done" in printed and " left (" in printed
