"""`cec reproduce dual-destination`: the plan, the pipeline at a tiny budget, the report beside the paper."""

from __future__ import annotations

import copy
import dataclasses
import io
import json
import math
import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np
import pytest
import yaml

from apps.cli import main
from apps.reproduce import pipeline
from apps.reproduce.dual_destination import command as dd_command
from apps.reproduce.dual_destination import evaluate as dd_evaluate
from apps.reproduce.dual_destination import modes as dd_modes
from apps.reproduce.dual_destination import paper as dd_paper
from apps.reproduce.dual_destination import plan as dd_plan
from apps.reproduce.dual_destination import reasons as dd_reasons
from apps.reproduce.dual_destination import report as dd_report
from apps.reproduce.dual_destination import summary as dd_summary
from apps.zoo_build import plan_zoo
from cec import checkpoints
from cec.config import ConfigError
from cec.envs import dual_destination as dd
from cec.evaluation.results import make_table, read_csv
from cec.training.run import config_dict

TINY_NET = (
    "network_overrides={conv_features: [], encoder_features: [8], lstm_features: 4, actor_features: [8], "
    "critic_features: [8]}"
)
TINY = dd_modes.Mode(
    name="tiny",
    presets=dd_modes.QUICK.presets,
    seeds={"ippo": (0, 1, 2), "fcp": (100, 101, 102), "cec": (200, 201, 202)},
    steps={
        v: dict.fromkeys(dd_paper.ALGORITHMS, 1_600) for v in dd_paper.VARIANTS
    },  # 2 updates, 8 envs x 100 steps
    episodes={"fixed": 2, "generated": 1},
    overrides=("num_envs=8", "ppo.num_minibatches=2", "ppo.update_epochs=1", "updates_per_call=1", TINY_NET),
    generated_levels=2,
)


def test_the_plan_trains_fcp_on_the_ippo_seeds_and_cec_on_the_generator_of_each_variant(
    tmp_path: Path,
) -> None:
    for mode in (dd_modes.QUICK, dd_modes.FULL, dd_modes.PAPER_SCALE):
        for variant in dd_paper.VARIANTS:
            spec = dd_plan.zoo_spec(mode, variant)
            path = tmp_path / f"{mode.name}_{variant}.yaml"
            path.write_text(yaml.safe_dump(spec))
            plan = plan_zoo(path, tmp_path / f"zoo_{mode.name}_{variant}")  # the spec is valid as it stands
            by_algo = {run.algorithm: run for run in plan}  # the manifest's labels: ablations apart
            assert set(by_algo) == set(mode.rows) >= set(dd_paper.ALGORITHMS)
            ippo, fcp, cec = by_algo["ippo"], by_algo["fcp"], by_algo["cec"]
            assert ippo.seeds == mode.seeds["ippo"] and cec.seeds == mode.seeds["cec"]
            (population,) = fcp.config.partner.population
            assert Path(population.run) == ippo.run_dir and set(population.seeds) == set(mode.seeds["ippo"])
            assert ippo.config.checkpoint.milestones == (0.0, 0.5, 1.0)
            for run in plan:
                p = run.config.env.dual_destination
                assert bool(p.partial_obs) == (variant == "partial_obs")
                assert bool(p.multi_task) == (variant == "multi_task")
                assert run.config.total_env_steps == mode.steps[variant][run.algorithm]
            multi = variant == "multi_task"
            assert cec.config.env.levels == ("procedural_multi_task" if multi else "procedural")
            if "cec_nolstm" in by_algo:  # the ablation: CEC's config without its LSTM (and its own budget)
                ablation, net = by_algo["cec_nolstm"].config, cec.config.network_overrides
                assert ablation.network_overrides.lstm_features == 0 < net.lstm_features
                steps = cec.config.total_env_steps
                same = dataclasses.replace(ablation, network_overrides=net, total_env_steps=steps)
                c = cec.config
                assert dataclasses.replace(same, seed=c.seed, num_seeds=c.num_seeds, name=c.name) == c
            assert ippo.config.env.levels == fcp.config.env.levels == ("multi_task" if multi else "fixed")
    for mode in (dd_modes.FULL, dd_modes.PAPER_SCALE):
        lines = dd_plan.plan_lines(mode, tmp_path / mode.name)
        assert len(lines) == 3 * len(mode.rows) and all(ln.estimate_s > 0 for ln in lines)
        assert all(ln.done == 0.0 and ln.left_s == ln.estimate_s for ln in lines)
    assert "cec_nolstm" in dd_modes.FULL.rows


def test_the_plan_says_how_much_of_each_row_is_trained_and_what_is_left(tmp_path: Path) -> None:
    """A reproduction spans sessions: `--plan` reads the checkpoints under the work directory."""
    work = tmp_path / "work"
    plan = dd_plan.zoo(dd_modes.FULL, "partial_obs", work).plan()
    ippo = next(r for r in plan if r.algorithm == "ippo")  # 6 seeds in one run
    fcp = [r for r in plan if r.algorithm == "fcp"]  # 4 runs of one seed each
    state = {"w": np.zeros(2, np.float32)}
    for run, update in ((ippo, ippo.config.num_updates // 2), (fcp[0], fcp[0].config.num_updates)):
        path = checkpoints.CheckpointStore(run.run_dir, keep_last=1).path(update)
        checkpoints.save(path, state, update=update, env_steps=0, config=config_dict(run.config), metadata={})
    lines = {ln.run: ln for ln in dd_plan.plan_lines(dd_modes.FULL, work, ["partial_obs"])}
    assert lines["ippo"].done == pytest.approx(ippo.config.num_updates // 2 / ippo.config.num_updates)
    assert lines["fcp"].done == 0.25 and lines["fcp"].left_s == pytest.approx(0.75 * lines["fcp"].estimate_s)
    assert lines["cec"].done == 0.0
    out = io.StringIO()
    dd_command._print_plan(dd_modes.FULL, ["partial_obs"], work, tmp_path / "out", out)
    assert re.search(r"partial_obs +fcp .* 25% ", out.getvalue()) and ", left: " in out.getvalue()


def test_the_paper_numbers_are_data_and_a_malformed_file_names_the_file_and_the_key(tmp_path: Path) -> None:
    paper = dd_paper.load_paper()
    assert (paper.numbers, paper.claims, paper.oracle_fixed) == (
        dd_paper.PAPER,
        dd_paper.CLAIMS,
        dd_paper.ORACLE_FIXED,
    )
    assert dd_paper.paper_number("full_obs", "fixed", "cec") == dd_paper.PaperNumber(
        "full_obs", "fixed", "cec", 0.931, 0.013, "CEC scored 0.931 normalized reward (SE 0.013)"
    )
    figure_only = dd_paper.paper_number("full_obs", "fixed", "ippo")
    assert figure_only is not None and figure_only.mean is None and "figure only:" in figure_only.text
    assert dd_paper.ORACLE_FIXED == 0.955 and len(dd_paper.PAPER) == 15 and len(dd_paper.CLAIMS) == 13
    good = yaml.safe_load(dd_paper.PAPER_FILE.read_text())

    def broken(change: Callable[[dict[str, Any]], object]) -> dict[str, Any]:
        data = copy.deepcopy(good)
        change(data)
        return data

    cases = {
        "numbers[0].mean": broken(lambda d: d["numbers"][0].update(mean="high")),
        "numbers[1].variant": broken(lambda d: d["numbers"][1].update(variant="full")),
        "numbers[2].text": broken(lambda d: d["numbers"][2].update(mean=0.5)),  # a figure-only entry
        "numbers[3]": broken(lambda d: d["numbers"][3].pop("sem")),
        "claims[0].worse": broken(lambda d: d["claims"][0].update(worse="cec")),
        "oracle_fixed": broken(lambda d: d.update(oracle_fixed=None)),
        "(top level)": broken(lambda d: d.pop("claims")),
    }
    for key, data in cases.items():
        path = tmp_path / "paper.yaml"
        path.write_text(yaml.safe_dump(data))
        with pytest.raises(ConfigError, match=re.escape(f"{path}: {key}: ")):
            dd_paper.load_paper(path)


def test_the_plan_command_prints_every_run_and_the_expected_time(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    assert main(["reproduce", "dual-destination", "--plan", "--work", str(tmp_path / "full")]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") >= 11 and "training total:" in out and "?" not in out.split("training total:")[1]
    paper = ["reproduce", "dual-destination", "--paper", "--plan", "--work", str(tmp_path / "paper")]
    assert main(paper) == 0
    assert "(paper)" in capsys.readouterr().out
    assert main(["reproduce", "dual-destination", "--variants", "nope", "--plan"]) == 2
    assert "unknown variant" in capsys.readouterr().err


def test_the_committed_report_comes_back_from_its_work_folder_without_training_states(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`cec reproduce dual-destination --report-only` on the committed full version's work folder (tables,
    conventions, metrics; no policy, no training state): the committed numbers and conventions."""
    full = dd_plan.ROOT / "benchmarks" / "results" / "dual_destination" / "full"
    cmd = [sys.executable, "-m", "apps.cli", "reproduce", "dual-destination", "--report-only",
           "--allow-dirty", "--variants", "full_obs", "--work", str(full / "work"),
           "--out", str(tmp_path)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=dd_plan.ROOT, timeout=300)
    assert done.returncode == 0, done.stderr
    got, want = (json.loads((d / "summary.json").read_text()) for d in (tmp_path, full))
    assert got["summaries"]["full_obs"] == want["summaries"]["full_obs"]
    assert got["meta"]["conventions"]["full_obs"] == want["meta"]["conventions"]["full_obs"]
    assert main(["reproduce", "dual-destination", "--report-only", "--train-only"]) == 2
    empty = [
        "reproduce",
        "dual-destination",
        "--report-only",
        "--allow-dirty",
        "--work",
        str(tmp_path / "no"),
    ]
    assert main(empty) == 2


def test_train_only_goes_on_with_the_next_variant_while_others_train_the_rest(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two processes share a reproduction: one whose variant's remaining runs the other trains does not
    wait on them while a later variant has work; it comes back to the first variant at the end."""
    from apps import zoo_build

    calls = []

    def fake_build(spec, out, *, progress, log, wait, between=None):
        variant = Path(out).parent.name
        calls.append((variant, wait))
        if variant == "full_obs" and not wait:  # its CEC run is another process's
            return zoo_build.BuildResult(None, (), ("ippo-s0",), False, left=("cec-s200",))
        return zoo_build.BuildResult(Path(out) / "zoo.yaml", ("x",), (), False)

    monkeypatch.setattr(zoo_build, "build_zoo", fake_build)
    log = io.StringIO()
    manifests = dd_plan.train_only(
        dd_modes.FULL, tmp_path, ("full_obs", "partial_obs"), progress=False, log=log
    )
    assert calls == [("full_obs", False), ("partial_obs", False), ("full_obs", True)]
    assert list(manifests) == ["full_obs", "partial_obs"]
    assert manifests["full_obs"] == tmp_path / "full_obs" / "zoo" / "zoo.yaml"
    assert "full_obs: cec-s200 trained by other processes; back to it at the end" in log.getvalue()


@pytest.mark.slow
def test_the_pipeline_at_a_tiny_budget_writes_the_report_beside_the_paper(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # training alone (`--train-only`, as several processes or sessions share it), then the report reuses it
    manifests = dd_plan.train_only(TINY, tmp_path / "work", ("full_obs",), progress=False, log=io.StringIO())
    assert manifests["full_obs"].is_file() and not (tmp_path / "out").exists()
    log = io.StringIO()
    report = dd_command.reproduce_dual_destination(
        TINY, tmp_path / "out", tmp_path / "work", variants=("full_obs",), progress=False, log=log
    )
    assert log.getvalue().count("finished, skipping") == 3
    text = report.read_text()
    # our numbers beside the paper's, with the number of seeds (the units of the tests)
    rows = [ln for ln in text.splitlines() if ln.startswith("| Fully observable |")]
    cec_fixed = next(ln for ln in rows if "fixed task | CEC" in ln)
    assert "0.931 ± 0.013" in cec_fixed and "| 3 |" in cec_fixed
    assert "0.966" in next(ln for ln in rows if "generated tasks | CEC" in ln)
    assert "figure only" in next(ln for ln in rows if "fixed task | FCP" in ln)
    # the orderings with their tests, and the tolerance check of CEC's fully observable scores
    assert "leave-one-seed-out jackknife standard error" in text  # seeds as units, shared pairs counted
    orderings = [ln for ln in text.splitlines() if "| CEC > FCP |" in ln or "| FCP > IPPO |" in ln]
    assert len(orderings) == 3
    assert "CEC, fully observable, fixed task:" in text and "Machine:" in text
    assert (tmp_path / "out" / "bars_full_obs.png").stat().st_size > 1000
    assert (tmp_path / "out" / "curves_full_obs.png").stat().st_size > 1000
    assert "(curves_full_obs.png)" in text  # linked from the Training section

    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    claims = summary["claims"]
    assert {(c["better"], c["worse"], c["level_set"]) for c in claims} == {
        ("cec", "fcp", "fixed"), ("cec", "ippo", "fixed"), ("fcp", "ippo", "fixed"),
        ("cec", "fcp", "generated"), ("cec", "ippo", "generated"),
    }  # fmt: skip
    for c in claims:  # p is NaN only where both samples are constant (untrained policies may tie)
        assert math.isnan(c["p"]) or 0.0 <= c["p"] <= 1.0
        assert c["significant"] == (c["holds"] and not math.isnan(c["p"]) and c["p"] < dd_summary.ALPHA)

    # the numbers come from the result table written beside the zoo
    table = read_csv(tmp_path / "work" / "full_obs" / "results.csv")
    sp = (table.policy_a == dd_paper.ORACLE) & (table.policy_b == dd_paper.ORACLE)
    assert len(table.returns[sp]) == 2 * 1 + 2 * 1  # 2 episodes on the fixed task, 1 on each of 2 generated
    fixed = sp & (table.level == "fixed")
    assert np.all(table.returns[fixed] == dd.oracle_return(dd.fixed_level()))
    xp = summary["summaries"]["full_obs"]["fixed"]["xp"]["cec"]
    pairs = (table.algorithm_a == "cec") & (table.algorithm_b == "cec") & (table.seed_a != table.seed_b)
    assert xp["n"] == 3 and xp["n_seeds"] == 3
    sampled = table.actions == "sampled"
    assert xp["mean"] == pytest.approx(table.returns[pairs & sampled & (table.level == "fixed")].mean() / 200)
    # greedy play of the seeds among themselves, without the oracle; the conventions of every seed
    greedy = table.actions == "greedy"
    assert np.any(greedy) and not np.any(
        greedy & ((table.policy_a == dd_paper.ORACLE) | (table.policy_b == dd_paper.ORACLE))
    )
    kinds = summary["summaries"]["full_obs"]["fixed"]
    assert {"xp", "sp", "oracle", "xp_clipped", "greedy_xp", "greedy_sp"} <= set(kinds)
    assert kinds["xp_clipped"]["cec"]["mean"] >= xp["mean"] and kinds["greedy_xp"]["cec"]["n"] == 3
    seat0 = summary["meta"]["conventions"]["full_obs"]
    assert {a: sorted(map(int, v)) for a, v in seat0.items()} == {
        "ippo": [0, 1, 2], "fcp": [100, 101, 102], "cec": [200, 201, 202],
    }  # fmt: skip
    assert all(
        g == "no goal" or g.startswith(("green (", "pink (")) for v in seat0.values() for g in v.values()
    )
    assert "## Conventions" in text and "entropy at the end" in text
    assert re.search(r"\| 200: (never|[0-9.]+e\+0\d), 201: (never|[0-9.]+e\+0\d), 202: ", text)  # take-offs

    # a second run resumes: nothing is trained or played again, and the report is the same
    log2 = io.StringIO()
    again = dd_command.reproduce_dual_destination(
        TINY, tmp_path / "out", tmp_path / "work", variants=("full_obs",), progress=False, log=log2
    )
    assert log2.getvalue().count("finished, skipping") == 3
    assert "cross-play results found" in log2.getvalue()
    summary2 = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary2["summaries"] == summary["summaries"]
    played = summary["meta"]["played_s"]["full_obs"]  # the time playing took, kept while the table is
    assert played > 0 and summary2["meta"]["played_s"]["full_obs"] == played
    assert again == report

    # evaluated with other settings, the variant is played again
    log3 = io.StringIO()
    more = dd_modes.Mode(**{**TINY.__dict__, "episodes": {"fixed": 3, "generated": 1}})
    dd_command.reproduce_dual_destination(
        more, tmp_path / "out", tmp_path / "work", variants=("full_obs",), progress=False, log=log3
    )
    assert "cross-play results found" not in log3.getvalue()
    table = read_csv(tmp_path / "work" / "full_obs" / "results.csv")
    sp = (table.policy_a == dd_paper.ORACLE) & (table.policy_b == dd_paper.ORACLE)
    assert len(table.returns[sp]) == 3 * 1 + 1 * 2  # now 3 episodes on the fixed task

    # so is it once the oracle partner's code changed: what the table depends on includes its source
    manifest = tmp_path / "work" / "full_obs" / "zoo" / "zoo.yaml"
    key = dd_evaluate.evaluation_key(more, "full_obs", manifest)
    monkeypatch.setattr(dd_evaluate, "oracle_partner_digest", lambda: "another oracle")
    assert dd_evaluate.evaluation_key(more, "full_obs", manifest) != key

    # the exported policies are what `cec eval` plays; the conventions found are kept beside the table
    policies = tmp_path / "work" / "full_obs" / "policies"
    assert {e["name"] for e in yaml.safe_load((policies / "zoo.yaml").read_text())["policies"]} == {
        f"{a}-s{n}" for a, seeds in (("ippo", (0, 1, 2)), ("fcp", (100, 101, 102)), ("cec", (200, 201, 202)))
        for n in seeds
    }  # fmt: skip
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    # the exported policies are their checkpoints' parameters, exactly
    exported = {p.name: p for p in pipeline.load_zoo_policies(policies / "zoo.yaml", "exported")}
    for state in pipeline.load_zoo_policies(manifest, "zoo"):
        same = jax.tree.map(np.array_equal, state.params, exported[state.name].params)
        assert all(jax.tree.leaves(same)) and exported[state.name].network == state.network, state.name
    # committed without them: the report from the tables, the conventions found and the metrics CSVs
    for states in (tmp_path / "work" / "full_obs" / "zoo" / "runs").glob("*/checkpoints"):
        shutil.rmtree(states)
    shutil.rmtree(policies)
    for logged in (tmp_path / "work" / "full_obs" / "zoo" / "runs").glob("*/metrics.jsonl"):
        logged.unlink()
    (tmp_path / "out" / "summary.json").unlink()
    dd_command.reproduce_dual_destination(
        more, tmp_path / "out", tmp_path / "work", variants=("full_obs",), progress=False, log=io.StringIO(),
        report_only=True,
    )  # fmt: skip
    summary3 = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary3["summaries"] == summary["summaries"]
    assert summary3["meta"]["conventions"] == summary["meta"]["conventions"]
    assert summary3["meta"]["training"] == summary["meta"]["training"]
    with pytest.raises(ConfigError, match="results.csv"):
        dd_command.reproduce_dual_destination(
            TINY, tmp_path / "out", tmp_path / "empty", variants=("full_obs",), log=io.StringIO(),
            report_only=True,
        )  # fmt: skip


def _score(
    mean: float, n_seeds: int = 4, spread: float = 0.01, seeds: tuple[int, ...] = ()
) -> dd_summary.Score:
    samples = tuple(mean + spread * np.linspace(-1, 1, n_seeds))  # one per seed
    err = float(np.std(samples, ddof=1) / math.sqrt(len(samples)))
    return dd_summary.Score(
        float(np.mean(samples)), err, n_seeds, len(samples), samples, seeds or tuple(range(n_seeds))
    )


def test_xp_among_learned_seeds_leaves_out_a_seed_that_never_learned() -> None:
    """Three CEC seeds on one generated task: seeds 0 and 1 learned (SP 0.9) and play 0.9 together; seed 2
    never did (-0.5 with anyone). XP counts seed 2; XP among learned seeds does not."""
    names = "policy_a algorithm_a seed_a policy_b algorithm_b seed_b level seat episode returns deliveries"
    names += " collisions shaped_return env episode_steps actions"
    cols: dict[str, list[Any]] = {k: [] for k in names.split()}
    for i in range(3):
        for j in range(i, 3):
            ret = 180.0 if 2 not in (i, j) else -100.0
            row = (f"cec-s{i}", "cec", i, f"cec-s{j}", "cec", j, "generated_000", 0, 0, ret, 0, 0, 0.0,
                   "dual_destination", 100, "sampled")  # fmt: skip
            for k, v in zip(cols, row, strict=True):
                cols[k].append(v)
    kinds = dd_summary.summarise(make_table(cols), "full_obs")["generated"]
    assert kinds["sp"]["cec"].samples == (0.9, 0.9, -0.5) and kinds["sp"]["cec"].seeds == (0, 1, 2)
    assert kinds["xp"]["cec"].samples == pytest.approx((0.2, 0.2, -0.5))
    learned = kinds["xp_learned"]["cec"]
    assert (learned.samples, learned.seeds, learned.n, learned.n_seeds) == ((0.9, 0.9), (0, 1), 2, 3)


def test_the_report_states_differences_beyond_the_tolerance_and_failed_orderings(tmp_path: Path) -> None:
    fixed = {"cec": _score(0.94), "fcp": _score(0.60), "ippo": _score(0.70)}
    # the no-LSTM ablation: on generated tasks clearly below CEC; on the fixed task, above it
    generated = {"cec": _score(0.80), "fcp": _score(0.0), "ippo": _score(0.0), "cec_nolstm": _score(0.3)}
    fixed["cec_nolstm"] = _score(0.95)
    summaries = {
        "full_obs": {
            "fixed": {
                "xp": fixed,
                "sp": {"fcp": _score(0.42), "ippo": _score(0.72, spread=0.5)},  # IPPO seed 0 at 0.22
                "oracle": {"fcp": _score(0.86), "ippo": _score(0.8)},  # FCP: skill, not coordination
                "xp_clipped": {"cec": _score(0.95)},
                # IPPO: greedy, its seeds' conventions clash (XP well below SP); sampled play hides it
                "greedy_xp": {"ippo": _score(0.35)},
                "greedy_sp": {"ippo": _score(0.59)},
                "xp_learned": {"cec": _score(0.94), "fcp": _score(0.60)},
            },
            "generated": {"xp": generated, "sp": {"cec": _score(0.95)}, "oracle": {"cec": _score(0.9)}},
        },
        "partial_obs": {  # CEC learned (SP) but its seeds do not agree; FCP and IPPO fail on these tasks
            "generated": {
                "xp": {"cec": _score(0.5), "fcp": _score(-0.5), "ippo": _score(-0.49)},
                "sp": {"cec": _score(0.9), "fcp": _score(-0.5), "ippo": _score(-0.49)},
                "oracle": {"ippo": _score(-0.37)},  # the oracle partner alone reaches a goal now and then
            },
        },
    }
    meta = {
        "command": "cec reproduce dual-destination",
        "date": "2026-01-01",
        "git": "abc",
        "machine": {"cpu": "CPU", "cpu_count": 2, "device": "cpu:cpu", "host": "h", "jax": "0"},
        "wall_s": 60.0,
        "train_s": 50.0,
        "eval_s": 10.0,
        "why": "Why: a test.",
        "played_s": {"full_obs": 162.0, "partial_obs": None},
        "conventions": {"full_obs": {"ippo": {0: "green (4, 2)", 1: "green (0, 2)", 2: "green (0, 2)"}}},
        "training": {
            "full_obs": {
                algo: {"seeds": 4, "env_steps": 10, "seconds": 60.0, "final_return": end, "best_return": best}
                | ({"final_entropy": 0.45} if algo == "ippo" else {})
                | ({"late_slope": 0.002} if algo == "cec" else {})
                for algo, end, best in (("cec", 0.9, 0.92), ("cec_nolstm", -0.2, 0.05), ("ippo", 0.9, 0.95))
            },
            "partial_obs": {  # the ablation trained half CEC's budget here; one of its seeds learned
                "cec": {
                    "seeds": 4,
                    "env_steps": 20,
                    "seconds": 60.0,
                    "final_return": 0.5,
                    "best_return": 0.6,
                },
                "cec_nolstm": {
                    "seeds": 2,
                    "env_steps": 10,
                    "seconds": 60.0,
                    "final_return": -0.2,
                    "best_return": -0.1,
                    "best_by_seed": {"300": -0.45, "302": 0.9},
                },
            },  # fmt: skip
        },
    }
    text = dd_report.write_report(tmp_path, dd_modes.FULL, summaries, meta).read_text()
    cec_fixed = next(
        ln for ln in text.splitlines() if ln.startswith("| Fully observable | fixed task | CEC |")
    )
    assert "| 0.940 ± 0.004 | 0.950 ± 0.004 | — | — | 4 | 0.931 ± 0.013 |" in cec_fixed
    assert cec_fixed.endswith(
        "| raw | 0.940 ± 0.004 (4) |"
    )  # 0.940 is nearer the paper's 0.931 than the clipped 0.950
    ippo_fixed = next(
        ln for ln in text.splitlines() if ln.startswith("| Fully observable | fixed task | IPPO |")
    )
    assert "| 0.350 ± 0.004 | 0.590 ± 0.004 |" in ippo_fixed
    conventions = "0: green (4, 2) (0.22), 1: green (0, 2) (0.55), 2: green (0, 2) (0.89)"  # with each SP
    assert f"| Fully observable | IPPO | {conventions} | 2 |" in text
    assert "CEC, fully observable, fixed task: 0.940 vs the paper's 0.931: within 0.05." in text
    assert "generated tasks: 0.800 vs the paper's 0.966: **not within** (by 0.166)" in text
    line = next(ln for ln in text.splitlines() if ln.startswith("- Fully observable, held-out generated"))
    assert line.startswith("- Fully observable, held-out generated tasks, CEC: 0.800 vs 0.966 (-0.166).")
    assert "(SP) its seeds score 0.950 and with the oracle partner 0.900" in line
    assert "conventions that do not match across seeds" in line
    cec_gen = next(ln for ln in text.splitlines() if ln.startswith("- CEC, fully observable, held-out"))
    assert "Why: its seeds score 0.950 with themselves (SP), 0.150 above their XP" in cec_gen
    assert "ended at 0.900, changing +0.002 per 1e6 env steps" in cec_gen and "levelled off" in cec_gen
    cec_po = next(ln for ln in text.splitlines() if ln.startswith("- Partially observable") and "CEC" in ln)
    assert "conventions that do not match" in cec_po
    fcp_po = next(ln for ln in text.splitlines() if ln.startswith("- Partially observable") and "FCP:" in ln)
    assert "never trained on these tasks" in fcp_po  # FCP trained on the fixed task only
    assert "Why: a test." in text
    assert (  # reused work's recorded times: training from the runs' metrics, cross-play when played
        "whichever invocation did it: training fully observable 3 min, partially observable 2 min of one "
        "core (per algorithm in the Training section); cross-play fully observable 3 min, partially "
        "observable not recorded" in text
    )
    fcp_ippo = next(ln for ln in text.splitlines() if "fixed task | FCP > IPPO |" in ln)
    assert "| **no** | no |" in fcp_ippo  # the paper's FCP > IPPO does not hold here
    assert "- Fully observable, fixed task, FCP > IPPO: IPPO XP 0.700 vs SP" in text
    cec_fcp = next(ln for ln in text.splitlines() if "fixed task | CEC > FCP |" in ln)
    assert cec_fcp.endswith(", yes |") and "| yes | yes | +0.340, p " in cec_fcp  # learned seeds only
    assert "6 of 8 orderings hold, 6 of them significantly." in text
    po = next(ln for ln in text.splitlines() if ln.startswith("- Partially observable (3x3 view), held-out"))
    assert "neither FCP nor IPPO trained on these tasks" in po and "oracle" not in po
    assert "about as well as with themselves" not in po  # two failures: beside the point there
    reason = next(
        ln for ln in text.splitlines() if ln.startswith("- Fully observable, fixed task, FCP > IPPO")
    )
    assert "IPPO's seeds coordinate with each other about as well as with themselves" in reason
    assert "FCP also plays the task less well with itself than IPPO does" in reason
    assert "greedy, IPPO XP 0.350 vs SP 0.590: its seeds' conventions differ, and sampling hides it" in reason
    assert "IPPO's seeds send seat 0 to green (0, 2) (2), green (4, 2) (1)" in reason
    assert "policy entropy at the end of training IPPO 0.45 (uniform: 1.61)" in reason  # FCP's not known
    assert "1 of 4 IPPO seeds did not learn the task (SP < 0.5: seed 0)" in reason
    assert "4 of 4 FCP seeds did not learn the task" in reason
    assert "FCP scores 0.860 against SP 0.420: it can reach a goal pair, but does not coordinate" in reason
    assert "IPPO scores 0.800" not in reason  # IPPO learned the task (SP 0.72): no such line
    # the ablation: its own rows, its training return against the paper's claim, its seed-level tests
    # against CEC, outside the paper's orderings (still 8)
    section = text.split("## Ablation: CEC without an LSTM")[1].split("\n## ")[0]
    assert "cannot achieve a positive reward" in section and "`network_overrides.lstm_features=0`" in section
    assert "| Fully observable | 10 / 10 | 0.050 / -0.200 | 0.920 / 0.900 | yes |" in section
    po = "| Partially observable (3x3 view) | 10 / 20 | -0.100 / -0.200 | 0.600 / 0.500 |"
    assert po + " not the mean over seeds; 1 of 2 seeds did (302: best 0.90) |" in section
    assert "but, partially observable (3x3 view), a smaller budget than CEC's" in section
    assert "favours CEC's longer training" in section
    gen = next(ln for ln in section.splitlines() if ln.startswith("| Fully observable | held-out"))
    assert "| 0.800 ± 0.004 | 0.300 ± 0.004 | +0.500" in gen and gen.endswith("| yes (significant) |")
    fix = next(ln for ln in section.splitlines() if ln.startswith("| Fully observable | fixed task"))
    assert fix.endswith("| **no** |")
    assert "| Fully observable | held-out generated tasks | CEC_NOLSTM | 0.300 ± 0.004 |" in text


def test_training_stats_pool_the_runs_of_one_algorithm(tmp_path: Path) -> None:
    """FCP trained one run per seed: the Training section counts every run's seeds and time, not the last."""
    for seed, ret in ((100, -0.2), (102, 0.6)):
        run = tmp_path / "runs" / f"fcp-s{seed}"
        run.mkdir(parents=True)
        speed = {"env_steps_per_s": 100.0, "entropy": 0.5}
        rows = [
            {"update": u, "seed": seed, "env_steps": 1000 * u, "normalised_return": ret + 0.1 * u, **speed}
            for u in (1, 2)
        ]
        (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    stats = dd_summary.training_stats(tmp_path)["fcp"]
    assert (stats.seeds, stats.env_steps, stats.seconds) == (2, 2000, 40.0)  # 2 runs x 2000 steps / 100 per s
    assert stats.final_return == pytest.approx(0.35) and stats.best_return == pytest.approx(0.4)
    assert stats.best_by_seed == pytest.approx({"100": 0.0, "102": 0.8})  # each seed's own best update
    assert stats.positive_at == {"100": None, "102": 1000}  # 0.0 is not a positive return


def test_a_failed_ordering_names_the_better_algorithm_s_split_conventions() -> None:
    """CEC > IPPO fails because IPPO's seeds all share one convention and CEC's, each playing the task
    with itself, split between two goals: the line says both, each from its own seeds."""
    claim = dd_summary.ClaimResult(
        "multi_task", "fixed", "cec", "ippo", -0.73, -1.2, -0.5, 0.06, False, False
    )
    kinds = {
        "xp": {"cec": _score(0.24), "ippo": _score(0.97, n_seeds=6)},
        "sp": {"cec": _score(0.97), "ippo": _score(0.97, n_seeds=6)},
    }
    conventions = {
        "ippo": dict.fromkeys(range(6), "green (0, 1)"),
        "cec": {200: "pink (4, 1)", 201: "green (0, 1)", 202: "pink (4, 1)", 203: "pink (4, 1)"},
    }
    reason = dd_reasons.ordering_reason(claim, kinds, conventions)
    assert "IPPO's seeds coordinate with each other about as well as with themselves" in reason
    assert "IPPO's seeds send seat 0 to green (0, 1) (6)" in reason
    assert (
        "CEC's seeds learned the task (SP 0.970) but do not share one convention: seat 0 to green (0, 1) "
        "(1), pink (4, 1) (3), so they fail with each other (XP 0.240)" in reason
    )
    agreeing = dict(kinds, xp={**kinds["xp"], "cec": _score(0.9)})  # CEC's seeds coordinate: no such part
    assert "do not share one convention" not in dd_reasons.ordering_reason(claim, agreeing, conventions)


def test_a_cec_gap_says_whether_more_training_would_close_it() -> None:
    """Fully observable CEC short of the paper's value: the report says whether its seeds fall short
    with themselves too, and what its learning curve's end predicts for more steps of the same training."""
    trained = {"seeds": 4, "env_steps": 1_000_000, "seconds": 3600.0, "final_return": 0.8}
    rising = dd_reasons.cec_gap_reason(_score(0.78), 0.966, _score(0.8), trained | {"late_slope": 0.05})
    assert "its seeds score 0.800 with themselves (SP)." not in rising  # the SP part goes on
    assert "above their XP" not in rising  # 0.02 apart: not a gap between seeds
    # 0.166 short at +0.05 per 1e6 steps: 3.3e6 more steps; this run took 1 h per 1e6 steps
    assert (
        "SP would gain the missing 0.166 in about 3.3e+06 more env steps per seed, 3.3 h of one core"
        in rising
    )
    flat = dd_reasons.cec_gap_reason(_score(0.78), 0.966, _score(0.8), trained | {"late_slope": -0.004})
    assert "changing -0.004 per 1e6 env steps" in flat and "levelled off" in flat and "gain" not in flat
    skilled = dd_reasons.cec_gap_reason(_score(0.5), 0.966, _score(0.95), trained | {"late_slope": 0.03})
    assert "0.450 above their XP" in skilled and "gain" not in skilled  # SP is at the paper's level
    assert (
        dd_reasons.cec_gap_reason(_score(0.5), 0.966, None, {})
        == "No self-play or training record to say why."
    )


def test_the_late_slope_is_the_end_of_each_seed_s_learning_curve(tmp_path: Path) -> None:
    """One seed rises 0.1 per 1e6 steps over its last quarter, the other is flat there: their mean."""
    run = tmp_path / "runs" / "cec-s200"
    run.mkdir(parents=True)
    rows = []
    for u in range(1, 13):
        steps = 250_000 * u
        rising = -0.5 + 0.1 * steps / 1e6
        flat = min(0.6, -0.5 + 0.5 * steps / 1e6)  # 0.6 from 2.2e6 steps on: flat in the last 3 updates
        rows += [
            {
                "update": u,
                "seed": 200,
                "env_steps": steps,
                "normalised_return": rising,
                "env_steps_per_s": 1e3,
            },
            {"update": u, "seed": 201, "env_steps": steps, "normalised_return": flat, "env_steps_per_s": 1e3},
        ]
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert dd_summary.training_stats(tmp_path)["cec"].late_slope == pytest.approx(0.05)
    assert math.isnan(dd_summary.return_slope([(0, 0.1), (1, 0.2)]))  # too few points to fit a line


@pytest.mark.parametrize("paper", [0.0, 0.03, 0.61])
def test_a_reason_never_contradicts_the_paper_value_printed_beside_it(paper: float) -> None:
    """A policy that never trained on a task set fails there (-0.5 on our scale); the reason names the
    paper's own value and calls the gap one of scale only when that value is a failure too."""
    from apps.reproduce.dual_destination.reasons import difference_reason
    from apps.reproduce.dual_destination.summary import Score

    xp = Score(-0.5, 0.0, 4, 4, (-0.5,) * 4)
    text = difference_reason(xp, paper, xp, None, trained_on_set=False)
    assert f"{paper:.2f}" in text
    if paper > 0.05:
        assert "one of scale" in text and "not one of scale" in text and "for the same failure" not in text
    else:
        assert "for the same failure" in text and "generalisation" not in text
