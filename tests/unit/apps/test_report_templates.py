"""Every report's prose lives in Markdown templates (`templates/*.md` beside its code), filled by name
through `cec.evaluation.markdown.Templates`: each template is rendered here through its real filler on small
inputs. `fill` refuses a hole without a value and a value without a hole; `Templates.filled` must then cover
every template of the folder, so none is left unused."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace

from apps.machine import machine_info
from apps.reproduce.dual_destination import modes as dd_modes
from apps.reproduce.dual_destination import report as dd_report
from apps.reproduce.overcooked import report as oc_report
from apps.reproduce.overcooked import sections as oc_sections
from apps.reproduce.overcooked.summary import SeedScores
from cec.evaluation import report as cec_report
from cec.evaluation.markdown import Templates
from cec.evaluation.results import make_table
from tests.unit.apps.test_reproduce_dual_destination import _score
from tests.unit.apps.test_reproduce_overcooked import TINY, _round_robin
from tests.unit.evaluation.test_evaluation_analysis import BASE, POLICIES, _table


def _every_template_filled(templates: Templates) -> None:
    assert templates.names(), f"no templates in {templates.folder}"
    assert templates.filled == templates.names(), f"never filled: {templates.names() - templates.filled}"
    for name in templates.names():  # a file's last line ends like any other
        assert (templates.folder / f"{name}.md").read_text().endswith("\n"), name


def test_every_overcooked_template_is_filled_by_its_section(tmp_path: Path) -> None:
    assert oc_report.TEMPLATES is oc_sections.TEMPLATES  # one folder, one record of what was filled
    oc_sections.TEMPLATES.filled.clear()
    mode = dataclasses.replace(TINY, generated_levels=1)
    table = _round_robin({"cec": 20.0, "ippo": 0.0})
    controls = _round_robin({"cec_untrained": 40.0})
    runs = tmp_path / "runs"
    run = runs / f"ippo_{mode.kitchens[0]}-s0"
    run.mkdir(parents=True)
    rising = "\n".join(f"{u},{u * 100},0,{u},0" for u in range(1, 21))
    (run / "metrics.csv").write_text(f"update,env_steps,seed,mean_return,mean_shaped_return\n{rising}\n")
    lines = oc_sections.analysis_lines(mode, table, runs, controls)
    assert "## Single-kitchen training: levelled off?" in lines
    kitchen = mode.kitchens[0]  # IPPO's self-play there delivers nothing: a failing baseline
    own = {"policy_a": [f"ippo_{kitchen}-s0"], "algorithm_a": ["ippo"], "seed_a": [0], "level": [kitchen]}
    own |= {"policy_b": own["policy_a"], "algorithm_b": ["ippo"], "seed_b": [0], "returns": [0.0]}
    own |= {k: [0] for k in ("seat", "episode", "deliveries", "collisions", "shaped_return")}
    own |= {"env": ["overcooked"], "episode_steps": [400], "actions": ["sampled"]}
    assert "## Baselines without a soup in their own kitchen" in oc_sections.failing_lines(
        mode, make_table(own), runs
    )
    point = SimpleNamespace(name="cec", env_steps=1000, seeds=(0, 1, 2), xp=1.0, xp_se=0.1, sp=2.0, sp_se=0.2)
    oc_sections.curve_lines([point], 1)
    seeds = (0, 1, 2)
    scores = {
        algo: SeedScores(seeds, (v, v, v), (v, v, v), (v, v, v), (v, v + 1, v + 2), ((v, v + 1, v),) * 3)
        for algo, v in (("cec", 10.0), ("ippo", 5.0))
    }
    ran_on = {"machine": machine_info(), "commit": "abc1234"}
    report = oc_report.write_report(
        mode, {"classic": scores}, tmp_path / "out", figures={}, plan=[], command="tiny", ran_on=ran_on,
        commit="abc1234", sections=lines,
    )  # fmt: skip
    assert "## CEC against the baselines" in report.read_text()
    _every_template_filled(oc_sections.TEMPLATES)


def test_every_dual_destination_template_is_filled_by_its_report(tmp_path: Path) -> None:
    dd_report.TEMPLATES.filled.clear()
    xp = {"cec": _score(0.9), "fcp": _score(0.6), "ippo": _score(0.5)}
    summaries = {
        "full_obs": {"fixed": {"xp": xp, "sp": {"ippo": _score(0.7)}, "oracle": {"ippo": _score(0.8)}}}
    }
    training = {"seeds": 4, "env_steps": 10, "seconds": 60.0, "final_return": 0.5, "best_return": 0.6}
    meta = {
        "command": "cec reproduce dual-destination", "date": "2026-01-01", "git": "abc", "wall_s": 60.0,
        "machine": {"cpu": "CPU", "cpu_count": 2, "device": "cpu:cpu", "host": "h", "jax": "0"},
        "train_s": 50.0, "eval_s": 10.0, "played_s": {"full_obs": 1.0},
        "conventions": {"full_obs": {"ippo": {0: "green (4, 2)", 1: "green (0, 2)"}}},
        "training": {"full_obs": {"ippo": training, "cec": training}},
    }  # fmt: skip
    text = dd_report.write_report(tmp_path, dd_modes.FULL, summaries, meta).read_text()
    assert "## Conventions" in text and "## Training" in text
    _every_template_filled(dd_report.TEMPLATES)


def test_every_cec_report_template_is_filled_by_its_section(tmp_path: Path) -> None:
    cec_report.TEMPLATES.filled.clear()
    base = {**BASE, "human_proxy": 60.0}

    def value(p: tuple[str, int], q: tuple[str, int], level: str, seat: int, ep: int) -> float:
        return (base[p[0]] + base[q[0]]) / 2 + (10 if level == "coord_ring" else 0) + 4 * seat + ep

    text = cec_report.write_report(_table([*POLICIES, ("human_proxy", 0)], value), tmp_path).read_text()
    assert "Human proxies" in text
    _every_template_filled(cec_report.TEMPLATES)
