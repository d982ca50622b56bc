"""`cec reproduce overcooked`: the plan, the whole pipeline at a tiny budget, the seed-level summary."""

from __future__ import annotations

import dataclasses
import gzip
import io
import json
import math
import re
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from apps import humans
from apps.cli import main
from apps.reproduce.overcooked import command as oc_command
from apps.reproduce.overcooked import evaluate as oc_evaluate
from apps.reproduce.overcooked import figures as oc_figures
from apps.reproduce.overcooked import modes as oc_modes
from apps.reproduce.overcooked import plan as oc_plan
from apps.reproduce.overcooked import report as oc_report
from apps.reproduce.overcooked import sections as oc_sections
from apps.reproduce.overcooked import summary as oc_summary
from apps.reproduce.pipeline import play_seconds, read_metrics, results_file, train_seconds
from apps.zoo_build import export_zoo
from cec.agents.zoo import SkippedEntry
from cec.checkpoints import code_version
from cec.config import ConfigError, load_config
from cec.evaluation.curves import metrics_file, read_curve, trailing_mean
from cec.evaluation.results import make_table, read_csv
from cec.humans.bc import BCConfig
from cec.training.config import TrainConfig
from cec.training.run import MetricsWriter

TINY_NET = (
    "network_overrides={conv_features: [], encoder_features: [8], lstm_features: 0, actor_features: [8], "
    "critic_features: [8], egocentric: true, cell_features: 2}"
)
TINY = oc_modes.Mode(
    name="tiny",
    preset=oc_modes.QUICK.preset,
    seeds={
        "cec": (200, 201),
        "cec_e3t": (400,),
        "ippo": (0, 1),
        "fcp": (100,),
        "e3t": (150,),
        "cec_finetune": (300, 301),
    },  # one seed where two add nothing the test reads: every agent meets every other (400-step games)
    steps={a: 256 for a in oc_modes.ALGORITHMS},  # 2 updates of 8 envs x 16 steps
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
    for mode in (oc_modes.QUICK, oc_modes.CPU, oc_modes.PAPER):
        lines = oc_plan.plan_lines(mode, tmp_path / mode.name)
        names = [p.run for p in lines]
        assert names[0] == f"cec-s{mode.seeds['cec'][0]}"
        for k in mode.kitchens:
            for algo in ("ippo", "fcp", "e3t"):
                assert f"{algo}_{k}-s{mode.seeds[algo][0]}" in names
            finetunes = [n for n in names if n.startswith(f"cec_finetune_{k}-")]
            assert len(finetunes) == len(mode.seeds["cec"])  # one per CEC seed
        assert all(p.estimate_s > 0 for p in lines) or mode is oc_modes.PAPER  # not measured on a CPU
    spec = yaml.safe_load((tmp_path / "cpu" / "spec.yaml").read_text())["entries"]
    fcp = next(e for e in spec if e["name"] == "fcp_cramped_room")
    assert "runs/ippo_cramped_room-s0, seeds: [0, 1, 2, 3, 4, 5]" in next(
        o for o in fcp["overrides"] if o.startswith("partner.population")
    )
    assert {e["preset"] for e in spec} == {str(oc_modes.ROOT / oc_modes.CPU.preset)}


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
    scores = oc_summary.seed_scores(table, ["generated_000"])["cec"]
    assert scores.seeds == (0, 1, 2)
    assert scores.xp == (30.0, 50.0, 40.0) and scores.sp == (80.0, 80.0, 100.0)
    assert scores.cook[0] == 20.0 and np.isnan(scores.cook[1])


def test_a_baseline_significantly_ahead_of_cec_reads_cec_behind() -> None:
    """The comparison names the direction it found; a significant loss is not printed as a mere 'no'."""
    rng = np.random.default_rng(0)
    base = {"cec": 10.0, "ippo": 80.0, "fcp": 11.0}
    rows = [
        (algo, a, b, base[algo] + rng.normal(0, 1)) for algo in base for a in range(4) for b in range(a, 4)
    ]
    n = len(rows)
    table = make_table({
        "policy_a": [f"{r[0]}{r[1]}" for r in rows], "algorithm_a": [r[0] for r in rows],
        "seed_a": [r[1] for r in rows], "policy_b": [f"{r[0]}{r[2]}" for r in rows],
        "algorithm_b": [r[0] for r in rows], "seed_b": [r[2] for r in rows], "level": ["generated_000"] * n,
        "seat": [0] * n, "episode": [0] * n, "returns": [r[3] for r in rows], "deliveries": [0] * n,
        "collisions": [0] * n, "shaped_return": [0.0] * n, "env": ["overcooked"] * n,
        "episode_steps": [400] * n, "actions": ["sampled"] * n,
    })  # fmt: skip
    tests = oc_summary.comparisons({"heldout": oc_summary.seed_scores(table, ["generated_000"])})
    reading = {t["worse"]: oc_report._reading(t) for t in tests if t["measure"] == "xp"}
    assert reading == {"ippo": "CEC behind", "fcp": "no difference shown"}


def test_the_reading_claims_only_what_the_exact_test_holds_after_holm() -> None:
    """A t-test over 4 seeds a side can print a p the seeds cannot support: beside an exact p, the reading
    says which test shows the difference; without one (no pooled matrix), the t-test's reading alone."""
    base = {"significant": True, "diff": -30.0, "p": 0.001, "p_holm": 0.004}
    assert oc_report._reading({**base, "p_exact": math.nan, "p_exact_holm": math.nan}) == "CEC behind"
    assert oc_report._reading({**base, "p_exact": 0.0286, "p_exact_holm": 0.143}) == (
        "t-test: CEC behind; exact test: below 5%, not after Holm"
    )
    assert oc_report._reading({**base, "p_exact": 0.2, "p_exact_holm": 0.6, "p_holm": 0.09}) == (
        "t-test: CEC behind, not after Holm; exact test: not shown"
    )
    assert oc_report._reading({**base, "p_exact": 0.002, "p_exact_holm": 0.011}) == (
        "CEC behind (the exact test too, after Holm)"
    )
    assert oc_report._reading({**base, "significant": False}) == "no difference shown"


def test_the_human_proxy_tests_carry_the_two_sample_exact_p() -> None:
    """With the human proxies each seed meets the same fixed partners, so the seeds are independent: the
    exact test there relabels the per-seed scores (4 + 4 seeds: never below 2/70)."""
    from cec.evaluation.stats import permutation_two_sample

    def scores(human: tuple[float, ...]) -> oc_summary.SeedScores:
        return oc_summary.SeedScores((0, 1, 2, 3), (1.0,) * 4, (1.0,) * 4, (1.0,) * 4, human)

    summary = {"classic": {"cec": scores((10.0, 11.0, 12.0, 13.0)), "ippo": scores((1.0, 2.0, 3.0, 4.0))}}
    (test,) = [t for t in oc_summary.comparisons(summary) if t["measure"] == "human"]
    exact = permutation_two_sample([10.0, 11.0, 12.0, 13.0], [1.0, 2.0, 3.0, 4.0])
    assert (test["p_exact"], test["p_min"]) == (exact.p, exact.p_min) and exact.p == pytest.approx(2 / 70)
    assert test["p_exact_holm"] == pytest.approx(2 / 70)  # a family of one


def test_the_report_states_the_exact_tests_floor_at_the_seed_counts_it_has() -> None:
    """The sentence on what the exact test cannot go below is the report's own seed counts' (4 a side: 2/70,
    5 tests: 0.143 after Holm; 6 a side: 2/924 and 0.0108), not a fixed text."""
    from cec.evaluation.seeds import seed_matrix

    for seeds, floor, holm_floor in ((4, "0.0286", "0.143"), (6, "0.00216", "0.0108")):
        table = _round_robin(
            {"cec": 10.0, **{a: 80.0 for a in ("ippo", "fcp", "e3t", "cec_e3t", "cec_finetune")}}, seeds
        )
        summary = {"heldout": oc_summary.seed_scores(table, ["generated_000"])}
        tests = oc_summary.comparisons(summary, {"heldout": seed_matrix(table, ["generated_000"])})
        sentence = oc_report._floor_sentence(tests, summary)
        assert sentence.startswith(f"With {seeds} seeds each neither can go below {floor} ")
        assert f"with 5 tests in a family no Holm-adjusted exact p below {holm_floor}." in sentence
    assert oc_report._floor_sentence([], {}) == ""


def test_a_work_folder_without_a_100_step_table_says_why() -> None:
    lines = oc_report.steps_lines({"heldout": {}}, None)
    assert lines[0] == "## At the authors' 100-step episodes" and "Not played" in lines[2]


def _round_robin(base: dict[str, float], seeds: int = 4, *, across: bool = True) -> Any:
    """Every seed of every algorithm with every other (`across`: also across the algorithms), one
    held-out kitchen, the pair's return the mean of the two seeds' skills plus noise."""
    rng = np.random.default_rng(1)
    skill = {(a, s): base[a] + rng.normal(0, 1) for a in base for s in range(seeds)}
    agents = list(skill)
    rows = [(p, q, (skill[p] + skill[q]) / 2) for i, p in enumerate(agents) for q in agents[i:]
            if across or p[0] == q[0]]  # fmt: skip
    n = len(rows)
    return make_table({
        "policy_a": [f"{p[0]}{p[1]}" for p, _, _ in rows], "algorithm_a": [p[0] for p, _, _ in rows],
        "seed_a": [p[1] for p, _, _ in rows], "policy_b": [f"{q[0]}{q[1]}" for _, q, _ in rows],
        "algorithm_b": [q[0] for _, q, _ in rows], "seed_b": [q[1] for _, q, _ in rows],
        "level": ["generated_000"] * n, "seat": [0] * n, "episode": [0] * n,
        "returns": [r for *_, r in rows], "deliveries": [round(r / 20) for *_, r in rows],
        "collisions": [4] * n, "shaped_return": [0.0] * n, "env": ["overcooked"] * n,
        "episode_steps": [400] * n, "actions": ["sampled"] * n,
    })  # fmt: skip


def test_cross_play_tests_carry_the_exact_permutation_p_and_holm_within_each_family() -> None:
    """Beside the t-test: the exact p from CEC's and the baseline's pooled seed x seed matrix (4 + 4 seeds:
    never below 2/70) and every p Holm-adjusted within its level set and score; where the algorithms' seeds
    never met, no exact p (NaN) and the t-test alone."""
    from cec.evaluation.seeds import seed_matrix
    from cec.evaluation.stats import holm, permutation_crossplay

    table = _round_robin({"cec": 10.0, "ippo": 80.0, "fcp": 11.0})
    summary = {"heldout": oc_summary.seed_scores(table, ["generated_000"])}
    matrices = {"heldout": seed_matrix(table, ["generated_000"])}
    tests = [t for t in oc_summary.comparisons(summary, matrices) if t["measure"] == "xp"]
    assert [t["worse"] for t in tests] == ["fcp", "ippo"]
    sm = matrices["heldout"]
    for t in tests:
        idx = sm.indices("cec") + sm.indices(t["worse"])
        exact = permutation_crossplay(sm.scores[np.ix_(idx, idx)], 4)
        assert (t["p_exact"], t["p_min"]) == (exact.p, exact.p_min) and t["p_min"] == pytest.approx(2 / 70)
        assert t["family"] == 2
    assert [t["p_holm"] for t in tests] == list(holm([t["p"] for t in tests]))
    assert [t["p_exact_holm"] for t in tests] == list(holm([t["p_exact"] for t in tests]))
    ippo = tests[1]
    assert ippo["p_exact"] == pytest.approx(2 / 70) and ippo["p_exact_holm"] == pytest.approx(4 / 70)
    # only within-algorithm games: no pooled matrix, the t-test alone
    apart = _round_robin({"cec": 10.0, "ippo": 80.0, "fcp": 11.0}, across=False)
    tests = oc_summary.comparisons(
        {"heldout": oc_summary.seed_scores(apart, ["generated_000"])},
        {"heldout": seed_matrix(apart, ["generated_000"])},
    )
    assert tests and all(math.isnan(t["p_exact"]) and math.isfinite(t["p_holm"]) for t in tests)


def test_collisions_are_also_given_per_soup_beside_the_untrained_control() -> None:
    table = _round_robin({"cec": 20.0, "ippo": 0.0})  # 4 collisions per episode; IPPO delivers nothing
    controls = _round_robin({oc_modes.UNTRAINED: 40.0})
    mode = dataclasses.replace(TINY, generated_levels=1)
    lines = oc_sections.episode_lines(mode, table, controls)
    head = next(line for line in lines if line.startswith("| algorithm | collisions, classic"))
    assert head.endswith("| per soup, classic | per soup, held-out |")
    rows = {line.split(" | ")[0]: line for line in lines if line.startswith("| ") and "per soup" not in line}
    cec = table.select(
        (table.algorithm_a == "cec") & (table.algorithm_b == "cec") & (table.seed_a != table.seed_b)
    )
    assert rows["| CEC"].endswith(f"| {cec.collisions.sum() / cec.deliveries.sum():.1f} |")
    assert rows["| IPPO"].endswith("| — | — |")  # no soup: no collisions per soup
    assert rows["| control: untrained CEC network"].endswith("| — | 2.0 |")  # 4 per 2 soups


def test_lineups_play_every_game_once_kitchen_by_kitchen_one_algorithm_at_a_time() -> None:
    from cec.agents.policy import scripted_policy
    from cec.evaluation.crossplay import plan_games

    def agent(algo: str, seed: int, kitchen: str | None = None) -> object:
        name = f"{algo}_{kitchen}-s{seed}" if kitchen else f"{algo}-s{seed}"
        levels = (kitchen,) if kitchen else None
        return scripted_policy("noop", name, algorithm=algo, seed=seed, levels=levels)

    mode = dataclasses.replace(TINY, kitchens=("cramped_room", "coord_ring"))
    zoo = [agent("cec", 200), agent("cec", 201)]
    zoo += [agent(a, s, k) for k in ("cramped_room", "coord_ring") for a in ("fcp", "ippo") for s in (0, 1)]
    classic = oc_evaluate.lineups(mode, zoo, "classic")
    assert [p.name for p in classic] == [
        "cramped_room-generalists", "cramped_room-ippo", "cramped_room-fcp",
        "coord_ring-generalists", "coord_ring-ippo", "coord_ring-fcp",
    ]  # fmt: skip  # FCP, trained from IPPO's checkpoints, after it
    fcp = classic[2]
    assert fcp.levels == "cramped_room" and fcp.involving == {"fcp_cramped_room-s0", "fcp_cramped_room-s1"}
    assert [p.name for p in fcp.players] == ["cec-s200", "cec-s201", "ippo_cramped_room-s0",
                                             "ippo_cramped_room-s1", "fcp_cramped_room-s0",
                                             "fcp_cramped_room-s1"]  # fmt: skip
    held = oc_evaluate.lineups(mode, zoo, "heldout")
    assert [p.name for p in held] == [
        "generalists",
        "cramped_room-ippo",
        "cramped_room-fcp",
        "coord_ring-ippo",
        "coord_ring-fcp",
    ]
    assert held[0].involving is None and all(p.levels is None for part in held for p in part.players)
    assert {part.levels for part in held} == {oc_evaluate.level_spec(mode, "heldout")}

    def seated(players: list, levels: list[str], involving: frozenset[str] | None = None) -> list:
        """The games as (seat 0, seat 1, level), by names."""
        return [
            (players[g.a if g.seat == 0 else g.b].name, players[g.b if g.seat == 0 else g.a].name, levels[i])
            for g in plan_games(players, levels, "all", involving) for i in g.levels
        ]  # fmt: skip

    # every game once: on the classic kitchens every game of the zoo (each agent on its kitchens), on the
    # held-out ones the games of the generalists with each kitchen's agents (two kitchens' agents do not meet)
    everyone = seated(zoo, list(mode.kitchens))
    free = [dataclasses.replace(p, levels=None) for p in zoo]
    names = oc_evaluate.level_spec(mode, "heldout").split(",")
    by_kitchen = {
        game for k in mode.kitchens
        for game in seated([p for p in free if p.name.startswith("cec") or k in p.name], names)
    }  # fmt: skip
    for parts, games in ((classic, everyone), (held, by_kitchen)):
        played = [
            x for part in parts for x in seated(list(part.players), part.levels.split(","), part.involving)
        ]
        assert sorted(played) == sorted(games), parts[0].level_set


def test_a_baseline_without_a_soup_in_its_own_kitchen_is_explained_from_its_training(tmp_path: Path) -> None:
    """FCP's population delivered from its first update; E3T never delivered in training; IPPO delivered
    with itself in training, not in the evaluation."""
    rows = [("fcp", 100, 0.0, "cramped_room"), ("fcp", 101, 0.0, "cramped_room"),
            ("e3t", 150, 0.0, "coord_ring"), ("ippo", 0, 60.0, "cramped_room"),
            ("fcp", 100, 40.0, "coord_ring"), ("ippo", 0, 0.0, "coord_ring")]  # fmt: skip
    n = len(rows)
    table = make_table({
        "policy_a": [f"{a}_{k}-s{s}" for a, s, _, k in rows], "algorithm_a": [r[0] for r in rows],
        "seed_a": [r[1] for r in rows], "policy_b": [f"{a}_{k}-s{s}" for a, s, _, k in rows],
        "algorithm_b": [r[0] for r in rows], "seed_b": [r[1] for r in rows], "level": [r[3] for r in rows],
        "seat": [0] * n, "episode": [0] * n, "returns": [r[2] for r in rows], "deliveries": [0] * n,
        "collisions": [0] * n, "shaped_return": [0.0] * n, "env": ["overcooked"] * n,
        "episode_steps": [400] * n, "actions": ["sampled"] * n,
    })  # fmt: skip
    runs = tmp_path / "runs"
    for run, first, last, steps in (("fcp_cramped_room-s100", 17.0, 24.0, 400),
                                    ("e3t_coord_ring-s150", 0.0, 0.0, 400),
                                    ("ippo_coord_ring-s0", 0.0, 30.0, 128)):  # fmt: skip
        (runs / run).mkdir(parents=True)
        lines = ["update,env_steps,seed,mean_return,mean_shaped_return"]
        lines += [f"{u},{u * 100},0,{first if u == 1 else last},12.5" for u in range(1, 21)]
        (runs / run / "metrics.csv").write_text("\n".join(lines) + "\n")
        (runs / run / "config.yaml").write_text(f"env:\n  overcooked:\n    max_steps: {steps}\n")
    mode = dataclasses.replace(TINY, kitchens=("cramped_room", "coord_ring"))
    text = "\n".join(oc_sections.failing_lines(mode, table, runs))
    fcp = next(line for line in text.splitlines() if line.startswith("| FCP | cramped_room"))
    assert "| 400 | 17.0 → 24.0 |" in fcp and "partners delivered from its first update" in fcp
    e3t = next(line for line in text.splitlines() if line.startswith("| E3T | coord_ring"))
    assert "| 400 | 0.0 → 0.0 | 12.5 |" in e3t and "no soup in training either" in e3t
    ippo = next(line for line in text.splitlines() if line.startswith("| IPPO | coord_ring"))
    assert "| 128 | 0.0 → 30.0 |" in ippo and "(with itself), not in these" in ippo
    assert "| IPPO | cramped_room" not in text and "| FCP | coord_ring" not in text  # they deliver there
    # whether each run levelled off: the return over its last 10 updates, its rise over the last quarter
    (runs / "ippo_cramped_room-s0").mkdir()
    rising = "\n".join(f"{u},{u * 100},0,{u},0" for u in range(1, 21))
    (runs / "ippo_cramped_room-s0" / "metrics.csv").write_text(
        f"update,env_steps,seed,mean_return,x\n{rising}\n"
    )
    plateau = oc_sections.plateau_lines(
        mode, runs
    )  # each algorithm's training episode as its runs recorded it
    assert (
        "| IPPO | 128 | 15.5 (+5.0) no | 30.0 (+0.0) yes |" in plateau
        and "| FCP | 400 | 24.0 (+0.0) yes | — |" in plateau
    )  # levelled off: a rise of at most 5% of the return over the last quarter
    # every group that had not, with how far it was still rising and where it stopped
    assert "3 of 4 groups levelled off. The others stopped, still rising" in "\n".join(plateau)
    rising = [line for line in plateau if line.startswith("- ")]
    assert rising == [
        "- IPPO, cramped_room: +5.0 over the last quarter, 32% of its 15.5, at 2,000 env steps per seed; "
        "its rise not slowing (+5.0 the quarter before), no length projected; another quarter costs 0.0 min "
        "per seed"
    ]  # a straight line: no plateau to project


@pytest.mark.parametrize("rho", [0.6, 0.8, 0.9])
def test_the_plateau_projection_finds_where_an_exponential_approach_levels_off(rho: float) -> None:
    """Three points of R(t) = 100 - 100 rho^t (t in quarters of the run: a half, three quarters, the end)
    give the first run length whose own last quarter rises by at most 5% of its return; a rise that is
    not slowing, or one already within 5%, projects nothing or the run itself."""

    def r(t: float) -> float:
        return 100 - 100 * rho**t

    truth = next(q for q in range(5, 65) if r(q) - r(0.75 * q) <= oc_sections.PLATEAU_SHARE * r(q))
    assert oc_sections.plateau_quarters(r(2), r(3), r(4)) == truth
    assert oc_sections.plateau_quarters(10.0, 20.0, 30.0) is None  # a straight line
    assert oc_sections.plateau_quarters(30.0, 20.0, 30.0) is None  # fell, then rose: no rate to read
    assert oc_sections.plateau_quarters(90.0, 99.0, 100.0) == 4  # levelled off already


def test_a_group_still_rising_but_slowing_is_given_the_cost_of_the_rest(tmp_path: Path) -> None:
    """A run whose return rises by less each quarter: the report projects how much longer it would have
    to run and what the rest costs per seed, from the training seconds its metrics record."""
    run = tmp_path / "runs" / "e3t_coord_ring-s150"
    run.mkdir(parents=True)
    returns = [100 - 100 * 0.8 ** (u / 10) for u in range(1, 41)]
    lines = ["update,env_steps,seed,mean_return,env_steps_per_s"]  # 60 s an update
    lines += [f"{u},{u * 600},150,{v},10" for u, v in enumerate(returns, 1)]
    (run / "metrics.csv").write_text("\n".join(lines) + "\n")
    mode = dataclasses.replace(TINY, kitchens=("coord_ring",))
    text = "\n".join(oc_sections.plateau_lines(mode, tmp_path / "runs"))
    assert "0 of 1 groups levelled off." in text and "Training the 1 projected group(s) on to it" in text
    line = next(x for x in text.splitlines() if x.startswith("- E3T, coord_ring:"))
    smooth = trailing_mean(np.array(returns), 10)  # the report reads the trailing mean of 10 updates
    quarters = oc_sections.plateau_quarters(smooth[19], smooth[29], smooth[39])
    assert quarters is not None and quarters > 4
    rest = 40 * (quarters / 4 - 1)  # minutes per seed beyond the 40 it ran
    end = f"projected to level off at {quarters / 4:g}x its run, the rest costing {rest:.1f} min per seed"
    assert line.endswith(end)


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_the_pipeline_trains_evaluates_and_reports_then_resumes_from_its_results(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # human proxies with the agents' (tiny) network, cloned from the first recorded game of each kitchen
    humans.import_games(tmp_path / "humans", games_per_kitchen=1, log=io.StringIO())
    network = load_config(TrainConfig, str(oc_modes.ROOT / TINY.preset), [TINY_NET]).network_config
    proxies = humans.train_proxies(
        tmp_path / "humans", tmp_path / "proxies", kitchens=["cramped_room"],
        config=BCConfig(epochs=1, network=network), log=io.StringIO(),
    )  # fmt: skip
    mode = dataclasses.replace(TINY, proxies=str(proxies))
    work, out, log = tmp_path / "work", tmp_path / "out", io.StringIO()
    monkeypatch.setattr(oc_evaluate, "PROGRESS_S", 0.0)  # every call of a line-up's play says how far it is
    report = oc_command.reproduce_overcooked(mode, work, out, progress=False, log=log, command="tiny")
    monkeypatch.undo()
    assert report is not None and report.exists()
    text = report.read_text()
    # the generalists' games with each other were played between training runs, before the zoo was whole
    trained = [m.start() for m in re.finditer(r"\): training \d+ updates", log.getvalue())]
    played = log.getvalue().find("heldout line-up generalists: 3 agents + the cook")  # CEC 2 seeds, CEC-E3T 1
    assert 0 <= played < trained[-1], log.getvalue()
    assert re.search(r"classic line-up cramped_room-fcp: (\d+) of \1 episodes \(100%\)", log.getvalue())
    assert oc_evaluate.played_lineups(mode, work) == (20, 20)  # `--plan`: 10 line-ups at 400 and 100 steps
    for needle in ("## The 1 classic kitchens", "## The 1 held-out kitchens", "| CEC |", "| IPPO |",
                   "| FCP |", "| E3T |", "| CEC-Finetune |", "| CEC-E3T |", "130.51 (text)", "≈70 (figure)",
                   "28.21 (text)", "(seeds as units)", "## Cross-algorithm play",
                   "## The held-out kitchens by training kitchen", "in their own kitchen",
                   "| with human proxies |", "The paper's human study", "| control: untrained CEC network |",
                   "| control: no-op agent |", "## Per kitchen, collisions",
                   "| cramped_room | held-out |", "## At the authors' 100-step episodes",
                   "| heldout | CEC |"):  # fmt: skip
        assert needle in text, needle
    short = read_csv(work / "steps100" / "results.csv")  # the same line-ups, cut at 100 steps
    assert set(short.episode_steps) == {100} and len(short) == len(read_csv(work / "results.csv"))
    # the recorded time of each training run and of the cross-play, kept for a report that reuses them
    assert "Recorded times of the work behind these numbers" in text and "not recorded" not in text
    assert (
        "Budget (env steps per seed): CEC 256 per model; CEC-E3T 256 per model; E3T, FCP, IPPO 256 per "
        in text
    )
    row = re.search(r"\| cec-s200 \| 2 \| 256 \| 2 \| [0-9.]+ min \|", text)
    assert row, text
    summary = json.loads((out / "summary.json").read_text())
    cec = summary["summary"]["heldout"]["cec"]
    assert cec["seeds"] == [200, 201] and len(cec["xp"]) == 2 and len(cec["cook"]) == 2
    assert all(np.isnan(cec["human"]))  # the proxies play their own (classic) kitchen only
    for algo in oc_modes.ALGORITHMS:  # every seed played both proxies on the classic kitchen
        human = summary["summary"]["classic"][algo]["human"]
        assert len(human) == len(TINY.seeds[algo]) and np.all(np.isfinite(human)), algo
    assert "human_proxy" not in summary["summary"]["classic"]  # partners, not an algorithm of the summary
    for control, seeds in (
        (oc_modes.UNTRAINED, [200, 201]),
        (oc_modes.NOOP, [0]),
    ):  # beside every score with the cook
        for level_set in oc_modes.LEVEL_SETS:
            scores = summary["summary"][level_set][control]
            assert scores["seeds"] == seeds and np.all(np.isfinite(scores["cook"])), (control, level_set)
    assert summary["summary"]["classic"][oc_modes.NOOP]["sp"] == [0.0]  # two agents that stay deliver nothing
    assert (work / "controls" / oc_modes.MACHINE_FILE).is_file()  # where they were played, for a later report
    assert summary["summary"]["heldout"]["ippo"]["seeds"] == [0, 1]  # single-kitchen agents play held-out
    assert (out / "curves_cec.png").exists() and (out / "cec_xp_heldout.gif").exists()
    # cross-play at each milestone checkpoint (the preset's 0.5 and 1.0 of 2 updates)
    curves = _section(text, "## Cross-play learning curves")
    for point in (
        "| CEC | 128 | 2 |",
        "| CEC | 256 | 2 |",
        "| CEC-E3T | 128 | 1 | — |",
        "| CEC-E3T | 256 | 1 | — |",
    ):
        assert point in curves, curves
    assert (out / "curves_xp.png").exists()
    # every agent met every other: CEC with each baseline on both level sets, `cec report` of those games
    played = read_csv(work / "results.csv")
    for level_set in oc_modes.LEVEL_SETS:
        on = np.isin(played.level, oc_evaluate.level_spec(mode, level_set).split(","))
        met = {(a, b) for a, b in zip(played.algorithm_a[on], played.algorithm_b[on], strict=True)}
        assert all(("cec", x) in met or (x, "cec") in met for x in oc_modes.ALGORITHMS), (level_set, met)
    assert "Cross-algorithm heatmap" in (out / "crossplay" / "report.md").read_text()
    # `--plan` counts the episodes each part of the evaluation plays, from the mode alone
    planned, tables = oc_evaluate.planned_episodes(mode), {}
    for level_set in oc_modes.LEVEL_SETS:
        tables[level_set] = int(
            np.isin(played.level, oc_evaluate.level_spec(mode, level_set).split(",")).sum()
        )
    for part, folder in (("controls", "controls"), ("curves", oc_evaluate.CURVES)):
        tables[part] = len(read_csv(work / folder / "results.csv"))
    assert planned == tables
    # a second invocation trains nothing and plays nothing again
    log = io.StringIO()
    oc_command.reproduce_overcooked(mode, work, out, progress=False, log=log, command="tiny")
    # the 400-step table, the 100-step one, the controls and the curves
    assert log.getvalue().count("not played again") == 4 and "finished, skipping" in log.getvalue()
    # an evaluation interrupted after its first line-up plays the others again, not that one: the same table
    first, manifest, real = (
        (work / "results.csv").read_bytes(),
        work / "zoo" / "zoo.yaml",
        oc_evaluate._play_lineup,
    )
    shutil.rmtree(work / oc_evaluate.PARTS)
    (work / "results.key.json").unlink()
    calls: list[float] = []  # how long each line-up played

    def timed(*args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter()
        out = real(*args, **kwargs)
        calls.append(time.perf_counter() - t0)
        return out

    def interrupted(*args: Any, **kwargs: Any) -> Any:  # the first line-up plays, then Ctrl-C
        if calls:
            raise KeyboardInterrupt
        return timed(*args, **kwargs)

    monkeypatch.setattr(oc_evaluate, "_play_lineup", interrupted)
    log = io.StringIO()  # Ctrl-C: no traceback, what was played is kept
    assert oc_command.reproduce_overcooked(mode, work, out, progress=False, log=log, command="tiny") is None
    assert "cross-play interrupted; the line-ups played are kept: run the same" in log.getvalue()
    monkeypatch.setattr(oc_evaluate, "_play_lineup", timed)
    log = io.StringIO()
    oc_evaluate.cached_evaluation(mode, manifest, work, log=log, commit="abc1234")
    monkeypatch.undo()
    assert "classic line-up cramped_room-generalists: cross-play results found" in log.getvalue()
    assert log.getvalue().count("not played again") == 1 and (work / "results.csv").read_bytes() == first
    assert len(calls) == 10 and play_seconds(work) >= sum(calls)  # the time includes the interrupted one's
    # a zoo whose single-kitchen runs are records (carried without parameters once their games were
    # played: scripts/carry_run.py save --record-only): nothing trained, every line-up read from its table
    for run in (work / "zoo" / "runs").glob("*_cramped_room-s*"):
        for checkpoint in (run / "checkpoints").glob("update_*"):
            (checkpoint / "state.msgpack").unlink()
            meta = json.loads((checkpoint / "meta.json").read_text())
            meta["metadata"]["record_only"] = "carried without parameters"
            (checkpoint / "meta.json").write_text(json.dumps(meta))
    for folder in (work, work / "steps100"):
        (folder / "results.key.json").unlink()  # the whole tables assembled again, from the line-ups'
    log = io.StringIO()
    assert oc_command.reproduce_overcooked(mode, work, out, progress=False, log=log, command="tiny")
    assert "training" not in log.getvalue() and "agents + the cook" not in log.getvalue(), log.getvalue()
    assert log.getvalue().count("cross-play results found") == 2 * 10 + 2  # 10 line-ups x 2 lengths; + 2
    assert (work / "results.csv").read_bytes() == first
    for section in ("## The 1 classic", "## Cross-algorithm play", "## At the authors' 100-step"):
        assert _section((out / "report.md").read_text(), section) == _section(text, section), section
    # the work folder brought back without its checkpoints (from a GPU machine): the report from its table,
    # the GIF from the exported CEC seeds, the machine that trained and played named
    export_zoo(work / "zoo" / "zoo.yaml", tmp_path / "shipped", names=["cec-s200", "cec-s201"])
    for ckpt in (work / "zoo" / "runs").glob("*/checkpoints"):
        shutil.rmtree(ckpt)
    for jsonl in (work / "zoo" / "runs").glob("*/metrics.jsonl"):  # as committed: config and metrics.csv,
        jsonl.unlink()
    long_run = work / "zoo" / "runs" / "cec-s200" / "metrics.csv"  # ... a long run's metrics gzipped
    long_run.with_name("metrics.csv.gz").write_bytes(gzip.compress(long_run.read_bytes()))
    long_run.unlink()
    (out / "cec_xp_heldout.gif").unlink()
    shutil.rmtree(work / "zoo" / "runs" / "cec_e3t-s400")  # as in a folder trained before the mode had it
    for folder in (work, work / "controls", work / oc_evaluate.CURVES):  # committed gzipped, read as they are
        plain = folder / "results.csv"
        (folder / "results.csv.gz").write_bytes(gzip.compress(plain.read_bytes()))
        plain.unlink()
    ran_on = json.loads((work / oc_modes.MACHINE_FILE).read_text())
    # ... by an earlier version of the mode (another preset and budget): the report says what was trained
    earlier = dataclasses.replace(mode, preset="configs/train/cec_overcooked_tts.yaml",
                                  steps={a: 2 * n for a, n in mode.steps.items()})  # fmt: skip
    log = io.StringIO()
    again = oc_command.reproduce_overcooked(
        earlier, work, tmp_path / "again", log=log, command="tiny", report_only=True,
        policies=tmp_path / "shipped" / "zoo.yaml",
    )  # fmt: skip
    assert again is not None
    assert "controls: cross-play results found" in log.getvalue()  # the folder's own untrained network
    for section in ("## The 1 classic", "## Cross-algorithm play", "## The held-out kitchens by training",
                    "## Cross-play learning curves", "## At the authors' 100-step"):  # fmt: skip
        assert _section(again.read_text(), section) == _section(text, section), section  # from the table
    finished_at = code_version(short=True)  # the invocation that assembled the table from records' line-ups
    assert ran_on["commit"] == finished_at  # the invocation that finished the table, not one that read it
    assert ran_on["trained_at"] == [
        oc_evaluate._short(code_version())
    ]  # as the agents' checkpoints record it
    assert f"Trained and played on: {ran_on['machine']['device']}" in again.read_text()
    assert (
        f"cross-play finished at commit {finished_at}; the agents' last checkpoints written at 1 commit ("
        in (again.read_text())
    )
    assert row.group(0) in again.read_text()  # its metrics kept the recorded time (from metrics.csv.gz)
    assert (tmp_path / "again" / "curves_cec.png").exists()
    assert "| cec_e3t-s400 |" not in again.read_text() and "Not in this work folder" in again.read_text()
    gif = tmp_path / "again" / "cec_xp_heldout.gif"
    assert gif.exists() and gif.with_suffix(".json").exists()  # the episode it replays, recorded beside it
    # ... and without the exported seeds (committed without them): the GIF in place is kept, its caption too
    drawn, caption = gif.read_bytes(), next(ln for ln in again.read_text().splitlines() if gif.name in ln)
    log = io.StringIO()
    kept = oc_command.reproduce_overcooked(earlier, work, tmp_path / "again", log=log, command="tiny",
                                           report_only=True)  # fmt: skip
    assert kept is not None and caption in kept.read_text().splitlines() and gif.read_bytes() == drawn
    assert f"{gif.name} kept as it is" in log.getvalue()
    gif.with_suffix(".json").unlink()  # a GIF whose episode is not recorded is not captioned as that one
    log = io.StringIO()
    assert (
        oc_figures.crossplay_gif(read_csv(results_file(work)), work / "zoo" / "zoo.yaml", gif, log=log) == {}
    )
    assert "no GIF" in log.getvalue()
    with pytest.raises(ConfigError, match="results.csv"):
        oc_command.reproduce_overcooked(TINY, tmp_path / "empty", out, log=io.StringIO(), report_only=True)


def _section(text: str, head: str) -> str:
    """The Markdown section that starts with `head`, up to the next `## ` heading."""
    start = text.index(head)
    end = text.find("\n## ", start + 1)
    return text[start : end if end >= 0 else None]


def test_proxies_that_cannot_play_are_named_with_the_reason() -> None:
    summary = {"classic": {"cec": oc_summary.SeedScores((200,), (10.0,), (20.0,), (30.0,), (math.nan,))}}
    skipped = [SkippedEntry("hp_cramped_room", "human_proxy", 0, "its network differs")]
    (line, _) = oc_report._human_lines(TINY, summary, skipped)
    assert line.endswith("not played (they could not play with the agents: its network differs).")


def test_plan_command_prints_runs_and_time(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["reproduce", "overcooked", "--quick", "--plan", "--work", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "cec-s200" in printed and "ippo_cramped_room-s0" in printed and "training: ~" in printed
    assert "0% done" in printed and " left (" in printed
    assert "then cross-play: 3,358 episodes of 400 steps (classic 288, heldout 2,420" in printed
    assert "line-ups played (each as soon as its agents are trained): 0 of 20" in printed


def test_a_run_committed_with_its_metrics_gzipped_reads_the_same(tmp_path: Path) -> None:
    """A long run's `metrics.csv` is committed as `metrics.csv.gz` (over 1 MiB plain): its curves, and the
    rows the reproduction's report reads its training time from, are those of the plain file."""
    run = tmp_path / "run"
    run.mkdir()
    rows = [
        {"update": u, "env_steps": 512 * u, "seed": s, "mean_return": u * s / 3, "env_steps_per_s": 900.0 + s}
        for u in (1, 2, 3)
        for s in (7, 8)
    ]
    MetricsWriter(run).write(rows)
    plain, written = read_curve(run, "mean_return"), read_metrics(run)  # from metrics.jsonl
    (run / "metrics.jsonl").unlink()  # a committed run keeps config.yaml and metrics.csv only
    assert read_metrics(run) == written
    (run / "metrics.csv.gz").write_bytes(gzip.compress((run / "metrics.csv").read_bytes()))
    (run / "metrics.csv").unlink()
    assert metrics_file(run).name == "metrics.csv.gz"
    assert read_metrics(run) == written and train_seconds(read_metrics(run)) == pytest.approx(
        train_seconds(rows)
    )
    assert train_seconds(rows) > 0
    for seed, (steps, values) in read_curve(run, "mean_return").items():
        np.testing.assert_array_equal(steps, plain[seed][0])
        np.testing.assert_allclose(values, plain[seed][1])
