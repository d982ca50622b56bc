"""`cec partners best|finetune`: on the committed tables they give back what ships (`cec/shipped/best.yaml`)
and the committed reports, byte for byte (the writer's line aside); they play what is not there (a tiny
fine-tuned run of random seeds, scripted partners) and ship the chosen seed; bad input stops them before
anything is played. The fail-closed cases (a skipped validation proxy) are in test_hardening_round4.py."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
import yaml

from cec import checkpoints
from cec.agents.policy import load_policy
from cec.agents.zoo import ZooEntry, load_zoo
from cec.config import from_dict
from cec.training.config import TrainConfig
from cec.training.run import config_dict
from cec.training.trainer import Trainer

REPO = Path(__file__).resolve().parents[3]
SHIPPED = REPO / "benchmarks/results/overcooked/shipped"
VALIDATION_TABLES = (
    f"cec={SHIPPED / 'heldout.csv'}",
    f"cec_teacher={SHIPPED / 'teacher/heldout.csv.bz2'}",
)


def _cec(*args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "apps.cli", "partners", *args]
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=900)


def _shipped_zoo(tmp: Path) -> Path:
    """A copy of the shipped zoo's manifest in a folder of its own, where --ship writes."""
    zoo = tmp / "shipped" / "zoo.yaml"
    zoo.parent.mkdir()
    shutil.copyfile(REPO / "cec/shipped/zoo.yaml", zoo)
    return zoo


def _tables(src: Path, dst: Path) -> Path:
    dst.mkdir(parents=True)
    for table in src.glob("*.csv.bz2"):
        shutil.copyfile(table, dst / table.name)
    return dst


def test_partners_best_gives_back_the_shipped_choice_from_the_committed_tables(tmp_path: Path) -> None:
    zoo, out = _shipped_zoo(tmp_path), _tables(SHIPPED / "best", tmp_path / "best")
    flags = [a for t in VALIDATION_TABLES for a in ("--validation-table", t)]
    done = _cec("best", "--out", str(out), "--zoo", str(zoo), *flags, "--ship")
    assert done.returncode == 0, done.stderr[-3000:]
    assert "playing" not in done.stderr  # every table read
    shipped = (zoo.parent / "best.yaml").read_text()
    assert yaml.safe_load(shipped) == yaml.safe_load((REPO / "cec/shipped/best.yaml").read_text())
    assert shipped == (REPO / "cec/shipped/best.yaml").read_text()
    assert (out / "best.yaml").read_text() == shipped
    assert (out / "best.md").read_text() == (SHIPPED / "best/best.md").read_text()


@pytest.mark.parametrize(("family", "folder"), [("ft758m", "finetune"), ("ftteach", "finetune/teacher")])
def test_partners_finetune_gives_back_the_committed_summary(tmp_path: Path, family: str, folder: str) -> None:
    out = _tables(SHIPPED / folder, tmp_path / "out")
    done = _cec("finetune", "--family", family, "--out", str(out))
    assert done.returncode == 0, done.stderr[-3000:]
    assert "playing" not in done.stderr
    for name in ("summary.json", "summary.md"):
        assert (out / name).read_text() == (SHIPPED / folder / name).read_text(), name
    shipped = {r["kitchen"]: r["shipped_seed"] for r in json.loads((out / "summary.json").read_text())}
    in_zoo = {e.name: e.seed for e in load_zoo(REPO / "cec/shipped/zoo.yaml")}
    assert {f"{family}-{k}": s for k, s in shipped.items()} == {
        f"{family}-{k}": in_zoo[f"{family}-{k}"] for k in shipped
    }


def test_partners_refuse_bad_input_before_playing(tmp_path: Path) -> None:
    done = _cec("best", "--out", str(tmp_path / "a"), "--validation-table", "cec_xyz=nowhere.csv")
    assert done.returncode == 2 and "GROUP=CSV" in done.stderr and "Traceback" not in done.stderr
    done = _cec("best", "--out", str(tmp_path / "b"), "--proxies", str(tmp_path / "none.yaml"))
    assert done.returncode == 2 and "cec humans bc" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "b").exists()
    done = _cec(
        "finetune", "--family", "ftteach", "--runs", str(tmp_path), "--out", str(tmp_path / "c"), "--ship"
    )
    assert done.returncode == 2, done.stderr
    assert "no ftteach run for cramped_room" in done.stderr and "cec train --config" in done.stderr
    assert not (tmp_path / "c").exists()
    done = _cec("finetune", "--family", "ftteach", "--kitchens", "kitchen_x")
    assert done.returncode == 2 and "not classic kitchens" in done.stderr


# ---- the play path: a tiny fine-tuned run of two random seeds, scripted partners ---------------------------

SEEDS = [30, 31]
ZOO = """# a test's shipped zoo
policies:
  - {name: gen_a, algorithm: cec_teacher, seed: 30, scripted: cook}
  - {name: gen_b, algorithm: cec_teacher, seed: 31, scripted: noop}
  - {name: hp_cramped_room, algorithm: human_proxy, seed: 0, scripted: cook, levels: [cramped_room]}
  - {name: other, algorithm: other, seed: 0, scripted: noop}
"""
PROXIES = "policies:\n  - {name: bc_cramped_room, seed: 0, scripted: cook, levels: [cramped_room]}\n"


def _run(runs: Path) -> Path:
    """A run `ftteach-cramped_room` of two seeds with random parameters (one checkpoint)."""
    config = from_dict(TrainConfig, {
        "algorithm": "ippo", "num_seeds": len(SEEDS), "seed": SEEDS[0], "num_envs": 2, "num_steps": 8,
        "total_env_steps": 64, "network": "small", "run_dir": str(runs), "name": "ftteach-cramped_room",
        "env": {"name": "overcooked", "levels": "cramped_room", "overcooked": {"max_steps": 16}},
    })  # fmt: skip
    template = Trainer(config).state_template()
    store = checkpoints.CheckpointStore(runs / "ftteach-cramped_room", keep_last=2)
    rng = np.random.default_rng(0)
    state = jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), template)
    params = jax.tree.map(lambda s: rng.normal(0.0, 0.5, s.shape).astype(s.dtype), template.params)
    store.save(state._replace(params=params), update=4, env_steps=64, config=config_dict(config),
               metadata={"algorithm": "ippo", "seeds": SEEDS}, milestone=False)  # fmt: skip
    return runs / "ftteach-cramped_room"


@pytest.mark.slow
def test_partners_finetune_plays_what_is_not_there_and_ships_the_seed_chosen_with_the_bc_proxy(
    tmp_path: Path,
) -> None:
    run = _run(tmp_path / "runs")
    zoo = tmp_path / "shipped" / "zoo.yaml"
    zoo.parent.mkdir()
    zoo.write_text(ZOO)
    (tmp_path / "proxies.yaml").write_text(PROXIES)
    out = tmp_path / "out"
    args = ["finetune", "--family", "ftteach", "--runs", str(tmp_path / "runs"), "--out", str(out),
            "--kitchens", "cramped_room", "--episodes", "1", "--max-steps", "24",
            "--proxies", str(tmp_path / "proxies.yaml"), "--zoo", str(zoo)]  # fmt: skip
    first = _cec(*args, "--ship")
    assert first.returncode == 0, first.stderr[-3000:]
    assert "playing cramped_room" in first.stderr
    (row,) = json.loads((out / "summary.json").read_text())
    bc = row["finetune"]["with_bc_proxy"]["per_seed"]
    assert row["finetune_seeds"] == SEEDS and row["shipped_seed"] == SEEDS[int(np.argmax(bc))]
    entries = {e.name: e for e in load_zoo(zoo)}
    assert list(entries) == ["gen_a", "gen_b", "hp_cramped_room", "other", "ftteach-cramped_room"]
    assert zoo.read_text().startswith("# a test's shipped zoo\n")
    shipped = entries["ftteach-cramped_room"]
    assert (shipped.algorithm, shipped.seed, shipped.levels) == (
        "cec_finetune_teacher",
        row["shipped_seed"],
        ("cramped_room",),
    )
    trained = load_policy(ZooEntry("x", str(run), seed=row["shipped_seed"]))
    for a, b in zip(
        jax.tree.leaves(load_policy(shipped).params), jax.tree.leaves(trained.params), strict=True
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # a second call reads its table, and ships in place of the entry it shipped before
    second = _cec(*args, "--ship")
    assert second.returncode == 0, second.stderr[-3000:]
    assert "playing" not in second.stderr and "reusing" in second.stderr
    assert [e.name for e in load_zoo(zoo)] == list(entries)


@pytest.mark.slow
def test_partners_best_plays_the_generalists_on_validation_when_no_table_is_given(tmp_path: Path) -> None:
    """The kitchens' committed tables, and the shipped generalists played on one validation kitchen."""
    out = _tables(SHIPPED / "best", tmp_path / "best")
    done = _cec("best", "--out", str(out), "--validation", "generated_000", "--max-steps", "24")
    assert done.returncode == 0, done.stderr[-3000:]
    assert "playing validation_cec:" in done.stderr and "playing validation_cec_teacher:" in done.stderr
    assert {"validation_cec.csv.bz2", "validation_cec_teacher.csv.bz2"} <= {p.name for p in out.iterdir()}
    report = (out / "best.md").read_text()
    assert (
        "on the 1 generated validation\nkitchens (one episode per pairing and kitchen, generated_000)"
        in report
    )
    choice = yaml.safe_load((out / "best.yaml").read_text())
    assert choice["other_kitchens"] in ("cec", "cec_teacher")
    assert {k: v for k, v in choice.items() if k != "other_kitchens"} == {
        k: v
        for k, v in yaml.safe_load((REPO / "cec/shipped/best.yaml").read_text()).items()
        if k != "other_kitchens"
    }
