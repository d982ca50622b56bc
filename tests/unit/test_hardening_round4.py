"""Fourth hardening round (issue 88) for the library and the `cec` commands that need no service: shipping
choices fail closed, a run's files are rewritten only after they are checked (and never in place), every
file is read in bounded memory (checkpoints hashed in chunks), a run stops at its first non-finite step,
settings have finite ranges, `cec levels sample` checks its arguments before compiling."""

from __future__ import annotations

import bz2
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from cec.agents.zoo import SkippedEntry
from cec.evaluation.choice import ChoiceError, choose

REPO = Path(__file__).resolve().parents[2]
SHIPPED = REPO / "benchmarks/results/overcooked/shipped"
DAMAGED = "checkpoint runs/humans/proxies/bc_cramped_room is corrupt: state.msgpack has SHA-256 0123"


def _cec(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "apps.cli", *args]
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=timeout)


# ---- a shipping choice fails closed ------------------------------------------------------------------------


def _without_bc(table: Path, out: Path) -> None:
    """`table` as `cec eval` writes it when it skipped the bc proxy (a damaged checkpoint): its rows gone,
    one skipped row naming it instead."""
    lines = bz2.decompress(table.read_bytes()).decode().splitlines()
    kept = [ln for ln in lines if ",bc_proxy," not in ln]
    assert len(kept) < len(lines)
    kept.append("bc_cramped_room,bc_proxy,0" + "," * 14 + f"skipped,{DAMAGED}")
    out.write_bytes(bz2.compress(("\n".join(kept) + "\n").encode()))


def test_choose_takes_the_highest_mean_and_the_first_on_a_tie():
    assert choose({"a": [1.0, 3.0], "b": [2.5]}, what="x") == "b"
    assert choose({"control": [2.0], "new": [1.0, 3.0]}, what="x") == "control"


@pytest.mark.parametrize(
    ("figures", "skipped", "cause"),
    [
        ({"a": [1.0], "b": []}, (), "b has no figure"),
        ({"a": [1.0], "b": [math.nan, 2.0]}, (), r"b has a figure that is not finite \(1 of 2 are nan\)"),
        ({"a": [math.inf]}, (), "a has a figure that is not finite"),
        ({}, (), "there is no candidate"),
        ({"a": [1.0]}, (SkippedEntry("bc_x", "bc_proxy", 0, "corrupt"),), "skipped 'bc_x' .*: corrupt"),
    ],
)
def test_choose_refuses_an_empty_or_non_finite_group_or_a_skipped_entry(figures, skipped, cause):
    with pytest.raises(ChoiceError, match=f"the seed: refusing to choose.*{cause}"):
        choose(figures, what="the seed", skipped=skipped)


def test_partners_finetune_refuses_to_ship_without_the_validation_proxy(tmp_path):
    """The committed Cramped Room table of the kickstarted family with the bc proxy skipped: before, seed 600
    shipped instead of 601, `best` flipped to cec_teacher and the script (now `cec partners finetune`) exited
    0. Nothing is written beside the table, nothing shipped."""
    out = tmp_path / "out"
    out.mkdir()
    _without_bc(SHIPPED / "finetune/teacher/cramped_room.csv.bz2", out / "cramped_room.csv.bz2")
    zoo = tmp_path / "shipped" / "zoo.yaml"
    zoo.parent.mkdir()
    shutil.copyfile(REPO / "cec/shipped/zoo.yaml", zoo)
    (tmp_path / "runs").mkdir()  # a checkpoint stands for the run, so that --ship gets to the choice
    (tmp_path / "runs" / "ftteach-cramped_room").symlink_to(REPO / "cec/shipped/ftteach-cramped_room")
    args = ("--family", "ftteach", "--kitchens", "cramped_room", "--out", str(out), "--zoo", str(zoo))
    done = _cec("partners", "finetune", *args, "--runs", str(tmp_path / "runs"), "--ship")
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert "refusing to choose" in done.stderr and "'bc_cramped_room'" in done.stderr
    assert DAMAGED in done.stderr
    assert "playing" not in done.stderr  # the table was read, not played again
    assert sorted(p.name for p in out.iterdir()) == ["cramped_room.csv.bz2"]  # no summary
    assert zoo.read_bytes() == (REPO / "cec/shipped/zoo.yaml").read_bytes()
    assert sorted(p.name for p in zoo.parent.iterdir()) == ["zoo.yaml"]  # nothing shipped


def test_partners_best_refuses_to_choose_without_the_validation_proxy(tmp_path):
    """`cec partners best` on the committed tables with Cramped Room's bc proxy skipped: a traceback before
    (best.py); now exit 2, and neither best.md nor best.yaml written or shipped."""
    tables = tmp_path / "best"
    tables.mkdir()
    for table in (SHIPPED / "best").glob("*.csv.bz2"):
        shutil.copyfile(table, tables / table.name)
    _without_bc(SHIPPED / "best/cramped_room_bc.csv.bz2", tables / "cramped_room_bc.csv.bz2")
    zoo = tmp_path / "shipped" / "zoo.yaml"
    zoo.parent.mkdir()
    shutil.copyfile(REPO / "cec/shipped/zoo.yaml", zoo)
    done = _cec("partners", "best", "--out", str(tables), "--zoo", str(zoo), "--ship")
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert "cramped_room: the partner of `--partner best`: refusing to choose" in done.stderr
    assert "'bc_cramped_room'" in done.stderr and DAMAGED in done.stderr
    assert not (tables / "best.md").exists() and not (tables / "best.yaml").exists()
    assert not (zoo.parent / "best.yaml").exists()


# ---- a resume never loses a row: checked, then written to a temporary file, then renamed ------------------

TINY = {
    "algorithm": "ippo",
    "num_envs": 2,
    "num_steps": 8,
    "total_env_steps": 64,  # 4 updates of 16 env steps
    "updates_per_call": 1,
    "network": "small",
    "network_overrides": {
        "conv_features": [], "encoder_features": [8], "lstm_features": 0, "actor_features": [8],
        "critic_features": [8],
    },
    "env": {"name": "overcooked", "levels": "cramped_room", "overcooked": {"max_steps": 8}},
    "checkpoint": {"every_updates": 1, "keep_last": 3, "milestones": []},
}  # fmt: skip


@pytest.fixture(scope="module")
def base_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A `cec train` run of 4 updates stopped after 2 (checkpoints at updates 1 and 2, rows 1-2). Copy it."""
    import yaml

    root = tmp_path_factory.mktemp("base")
    config = root / "tiny.yaml"
    config.write_text(yaml.safe_dump({**TINY, "run_dir": str(root / "runs"), "name": "tiny"}))
    done = _cec("train", "--config", str(config), "--max-updates", "2", "--quiet", timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return root / "runs" / "tiny"


@pytest.fixture
def run(base_run: Path, tmp_path: Path) -> Path:
    """A copy of `base_run` (resumed where it is: `cec train --resume` follows a moved run)."""
    copy = tmp_path / "tiny"
    shutil.copytree(base_run, copy)
    return copy


def _updates(run: Path) -> tuple[list[int], list[int]]:
    """The `update` of each row of metrics.jsonl and of metrics.csv (every line whole)."""
    import csv
    import json

    text = (run / "metrics.jsonl").read_text()
    assert text.endswith("\n")
    with open(run / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return [json.loads(ln)["update"] for ln in text.splitlines()], [int(r["update"]) for r in rows]


def test_a_resume_after_torn_last_lines_continues_from_the_last_whole_row(run):
    """What a full disk or a power cut leaves: a JSON row cut short, a blank line. Before: a JSON error that
    named no file, and the run could not be resumed."""
    with open(run / "metrics.jsonl", "a") as f:
        f.write('{"update": 3, "los')
    with open(run / "metrics.csv", "a") as f:
        f.write("\n")
    done = _cec("train", "--resume", str(run), "--max-updates", "1", "--quiet")
    assert done.returncode == 0, done.stderr[-3000:]
    for name in ("metrics.jsonl", "metrics.csv"):
        assert f"warning: {run / name}: its last line" in done.stderr
    assert _updates(run) == ([1, 2, 3], [1, 2, 3])
    assert not list(run.glob("*.tmp"))


def _extra_field(run: Path) -> None:
    lines = (run / "metrics.csv").read_bytes().split(b"\r\n")
    lines[1] += b",9"
    (run / "metrics.csv").write_bytes(b"\r\n".join(lines))


def _no_update_column(run: Path) -> None:
    (run / "metrics.csv").write_bytes(b"garbage;header\r\n" + (run / "metrics.csv").read_bytes())


def _jsonl_without_update(run: Path) -> None:
    lines = (run / "metrics.jsonl").read_text().splitlines()
    (run / "metrics.jsonl").write_text("\n".join([lines[0].replace('"update"', '"upd"'), *lines[1:]]) + "\n")


def _jsonl_not_json_mid_file(run: Path) -> None:
    lines = (run / "metrics.jsonl").read_text().splitlines()
    (run / "metrics.jsonl").write_text("\n".join([lines[0][:-3], *lines[1:]]) + "\n")


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (_extra_field, r"metrics.csv, line 2: the row has (\d+) fields, its header (?!\1)\d+"),
        (_no_update_column, "metrics.csv, line 1: the header has no `update` column"),
        (_jsonl_without_update, "metrics.jsonl, line 1: the row has no integer `update`"),
        (_jsonl_not_json_mid_file, "metrics.jsonl, line 1: not a JSON row"),
    ],
)
def test_a_malformed_metrics_file_stops_the_resume_naming_the_file_and_line_and_keeps_every_row(
    run, damage, message
):
    """A row with more fields than its header emptied metrics.csv to its header (and the next resume went on
    silently); a header or a JSON row without `update` was a KeyError traceback."""
    damage(run)
    before = {p.name: p.read_bytes() for p in run.glob("metrics.*")}
    done = _cec("train", "--resume", str(run), "--max-updates", "1", "--quiet")
    assert done.returncode == 2, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    assert re.search(message, done.stderr) and "the file was left as it was" in done.stderr
    assert {p.name: p.read_bytes() for p in run.glob("metrics.*")} == before
    assert not list(run.glob("*.tmp"))


def test_a_metrics_file_linked_to_a_device_is_refused_by_name(run):
    """metrics.csv linked to /dev/zero: a MemoryError before (that path skipped the bounded reader)."""
    (run / "metrics.csv").unlink()
    (run / "metrics.csv").symlink_to("/dev/zero")
    done = _cec("train", "--resume", str(run), "--max-updates", "1", "--quiet")
    assert done.returncode == 2, done.stderr[-3000:]
    assert f"metrics file '{run / 'metrics.csv'}' is not a regular file" in done.stderr
    assert "Traceback" not in done.stderr


# ---- every read of a checkpoint is bounded: its size against its metadata, chunked hashing -----------------

SPARSE = 6 << 30  # 6 GiB, allocated by no block


def _sparse(state: Path, size: int = SPARSE) -> None:
    with open(state, "r+b") as f:
        f.truncate(size)


@pytest.mark.parametrize(
    ("recorded", "size", "cause"),
    [
        (True, SPARSE, "state.msgpack holds 6,442,450,944 bytes, its metadata says"),
        (False, SPARSE, "more than 4,294,967,296, the most read .*CEC_CHECKPOINT_MAX_BYTES"),
        (False, 64 << 20, "state.msgpack has SHA-256"),  # no size recorded: hashed in chunks first
    ],
)
def test_a_huge_sparse_checkpoint_is_refused_in_bounded_memory(tmp_path, recorded, size, cause):
    """A 6 GB sparse state.msgpack was read whole before its checksum was checked: a MemoryError."""
    import json
    import tracemalloc

    import numpy as np

    from cec import checkpoints

    state = {"w": np.ones(3, np.float32)}
    path = checkpoints.save(tmp_path / "c", state, update=1, env_steps=2, config={}, metadata={})
    if not recorded:  # as written before checkpoints recorded their size
        meta = json.loads((path / "meta.json").read_text())
        del meta["size"]
        (path / "meta.json").write_text(json.dumps(meta))
    _sparse(path / "state.msgpack", size)
    tracemalloc.start()
    try:
        with pytest.raises(checkpoints.CorruptCheckpointError, match=cause):
            checkpoints.load(path, state)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 100 << 20, peak


def test_cec_train_resume_passes_over_a_huge_sparse_checkpoint_to_the_older_one(run):
    _sparse(run / "checkpoints/update_000000002/state.msgpack")
    done = _cec("train", "--resume", str(run), "--max-updates", "1", "--quiet")
    assert done.returncode == 0, done.stderr[-3000:]
    assert (
        "warning: passing over a damaged checkpoint" in done.stderr and "6,442,450,944 bytes" in done.stderr
    )
    assert "resuming" in done.stderr and "from update 1 (update_000000001)" in done.stderr
    assert _updates(run) == ([1, 2], [1, 2])


def test_cec_eval_skips_a_zoo_entry_with_a_huge_sparse_checkpoint_and_plays_the_others(run, tmp_path):
    import yaml

    _sparse(run / "checkpoints/update_000000002/state.msgpack")
    zoo = tmp_path / "zoo.yaml"
    zoo.write_text(
        yaml.safe_dump(
            {
                "policies": [
                    {
                        "name": "good",
                        "algorithm": "ippo",
                        "checkpoint": str(run / "checkpoints/update_000000001"),
                    },
                    {
                        "name": "bad",
                        "algorithm": "ippo",
                        "checkpoint": str(run / "checkpoints/update_000000002"),
                    },
                ]
            }
        )
    )
    out = tmp_path / "results.csv"
    args = ("--levels", "cramped_room", "--episodes", "1", "--max-steps", "8", "--out", str(out))
    done = _cec("eval", "--zoo", str(zoo), *args)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (
        "cec eval: skipping bad: CorruptCheckpointError: checkpoint" in done.stderr
        and "6,442,450,944 bytes" in done.stderr
    )
    from cec.evaluation.results import read_csv

    table = read_csv(out)
    assert set(table.policy_a) == {"good"} and [s.name for s in table.skipped] == ["bad"]


def test_cec_play_serve_refuses_a_huge_sparse_checkpoint_naming_it(run):
    pytest.importorskip("starlette")
    bad = run / "checkpoints/update_000000002"
    _sparse(bad / "state.msgpack")
    done = _cec("play", "serve", "--checkpoint", str(bad), "--port", "0", timeout=120)
    assert done.returncode == 2, done.stderr[-3000:]
    assert "Traceback" not in done.stderr and "6,442,450,944 bytes" in done.stderr


# ---- `cec levels sample` checks its arguments, and the generator its ranges, before compiling --------------


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--n", "100000000"], "--n must lie in [1, 100,000], got 100000000"),  # rc 134 inside XLA before
        (["--seed", str(2**64)], "--seed must lie in [0, 4,294,967,295]"),
        (["--tile-size", "20000"], "--tile-size must lie in [4, 256], got 20000"),
        (["--n", "5000", "--out", "{tmp}/sheet.png"], "lower --n or --tile-size"),
        (["--out", "{tmp}"], "is a folder; give a PNG file's name"),
        (["--out", "/dev/full"], "is not a regular file"),
        (["pots=[1,99]"], "pots max 99 is more than any of the structures"),  # XLA's top_k message before
        (["structure_weights=[1e308,1e308,1e308,1e308,1e308]"], "in that order, each at most 1e+06"),
        (["onion_piles=[1,22]", "plate_piles=[1,22]", "pots=[1,22]", "goals=[1,22]"], "add up to 88"),
    ],
)
def test_cec_levels_sample_refuses_out_of_range_arguments_naming_them(args, message, tmp_path):
    done = _cec("levels", "sample", *(a.replace("{tmp}", str(tmp_path)) for a in args), timeout=60)
    assert done.returncode == 2, done.stderr[-3000:]
    assert re.search(message if "\\" in message else re.escape(message), done.stderr), done.stderr
    assert "Traceback" not in done.stderr and "generated" not in done.stderr  # nothing was compiled


def test_cec_levels_sample_writes_within_its_bounds(tmp_path):
    out = tmp_path / "sheet.png"
    done = _cec("levels", "sample", "--n", "2", "--seed", str(2**32 - 1), "--out", str(out), "--ascii")
    assert done.returncode == 0, done.stderr[-3000:]
    assert out.stat().st_size > 0 and done.stdout.count("W") > 10


# ---- small: counts a run cannot have, names past their cap or with a NUL -----------------------------------


def test_a_checkpoint_claiming_more_updates_than_the_run_has_is_passed_over(run):
    """meta.json `update: 10**15` (its checksum intact): 'finished after 1000000000000000 updates' before."""
    import json

    meta_file = run / "checkpoints/update_000000002/meta.json"
    meta = json.loads(meta_file.read_text())
    meta_file.write_text(json.dumps({**meta, "update": 10**15}))
    done = _cec("train", "--resume", str(run), "--max-updates", "1", "--quiet")
    assert done.returncode == 0, done.stderr[-3000:]
    assert "update 1000000000000000 is past the run's last update, 4" in done.stderr
    assert "from update 1 (update_000000001)" in done.stderr
    assert "finished after 2 updates" in done.stdout


_HEADER = "policy_a,algorithm_a,seed_a,policy_b,algorithm_b,seed_b,level,seat,episode,return,deliveries," + (
    "collisions,shaped_return,env,episode_steps,actions,status,reason\n"
)
_OK = "cec0,cec,0,cec0,cec,0,cramped_room,0,0,20,1,0,3.5,overcooked,400,sampled,ok,\n"


@pytest.mark.parametrize(
    ("row", "cause"),
    [
        ("x" * 100_000 + ",cec,1" + "," * 14 + "skipped,damaged\n", "line 3: policy_a is longer than 256"),
        ("bad,cec,1" + "," * 14 + "skipped," + "r" * 3000 + "\n", "line 3: reason is longer than 2000"),
        ("ce\x00c1,cec,1,cec0,cec,0,cramped_room,0,0,20,1,0,3.5,overcooked,400,sampled,ok,\n", "control"),
        ("bad\x00,cec,1" + "," * 14 + "skipped,damaged\n", "line 3: policy_a holds the control character"),
    ],
)
def test_cec_report_refuses_a_name_past_its_cap_or_with_a_nul_in_any_row(tmp_path, row, cause):
    """A skipped row's 100,000-character name landed in report.md; a NUL in a name was accepted."""
    table = tmp_path / "results.csv"
    table.write_text(_HEADER + _OK + row)
    done = _cec("report", str(table), "--out", str(tmp_path / "report"), timeout=120)
    assert done.returncode == 2, done.stderr[-3000:]
    assert "Traceback" not in done.stderr and str(table) in done.stderr and cause in done.stderr
    assert not (tmp_path / "report" / "report.md").exists()


def test_cec_eval_refuses_a_zoo_entry_named_with_a_nul(tmp_path):
    zoo = tmp_path / "zoo.yaml"
    zoo.write_text('policies:\n  - {name: "cook\\0", scripted: cook}\n')
    done = _cec("eval", "--zoo", str(zoo), "--levels", "cramped_room", timeout=120)
    assert done.returncode == 2, done.stderr[-3000:]
    assert "`name` 'cook\\x00' must be at most 256 printable characters" in done.stderr


# ---- a run stops at its first non-finite update; settings have finite ranges ------------------------------


def _blown_up(base_run: Path, out: Path) -> Path:
    """A checkpoint of `base_run` whose parameters are finite but 1e30 times too large (it loads: every value
    is finite), so the first update from it is NaN."""
    import jax
    import numpy as np
    from flax import serialization

    from cec import checkpoints

    src = base_run / "checkpoints/update_000000002"
    meta = checkpoints.read_meta(src)
    raw = serialization.msgpack_restore((src / "state.msgpack").read_bytes())
    raw["params"] = jax.tree.map(lambda x: np.asarray(x) * np.float32(1e30), raw["params"])
    fields = {k: meta[k] for k in ("update", "env_steps", "config", "metadata")}
    return checkpoints.save(out, raw, **fields)


def _tiny_yaml(tmp_path: Path) -> Path:
    import yaml

    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump({**TINY, "run_dir": str(tmp_path / "runs"), "name": "ft"}))
    return path


@pytest.mark.parametrize(
    "distributed",
    [False, pytest.param(True, marks=pytest.mark.slow)],  # the learner's start: ~40 s on a loaded CPU
    ids=["cec-train", "learner-local-pool"],
)
def test_a_run_stops_at_its_first_non_finite_update_and_keeps_its_last_good_checkpoint(
    base_run, tmp_path, distributed
):
    """Nothing stopped a run whose loss was NaN: it trained on (ppo.teacher_coef=1e30: grad_norm=inf on every
    update, exit 0). Now the update is neither written nor saved, the checkpoint before it stays, exit 2."""
    start = _blown_up(base_run, tmp_path / "blown")
    args = ["algorithm=cec_finetune", f"init_from={start}", "checkpoint.milestones=[0.0]", "--quiet"]
    if distributed:  # the distributed learner, its actors in this process (what `cec up` runs)
        args += ["--distributed", "distributed.pool=local", "distributed.num_actors=1",
                 "distributed.publish_checkpoints=false", "distributed.metrics_port=0"]  # fmt: skip
    done = _cec("train", "--config", str(_tiny_yaml(tmp_path)), *args, timeout=400)
    assert done.returncode == 2, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    assert "update 1 (seed 0) is not finite (total_loss=nan" in done.stderr
    assert f"Look at init_from (the parameters it starts from: {start})" in done.stderr
    run = tmp_path / "runs" / "ft"
    assert f"its last good checkpoint is kept ({run}/checkpoints/update_000000000, update 0)" in done.stderr
    assert [p.name for p in (run / "checkpoints").iterdir()] == ["update_000000000"]
    assert not (run / "metrics.jsonl").exists() or not (run / "metrics.jsonl").read_text()


def test_the_setting_to_look_at_is_the_weight_of_the_largest_or_broken_term():
    from cec.config import from_dict
    from cec.training.config import TrainConfig
    from cec.training.loop import suspect

    config = from_dict(TrainConfig, {**TINY, "ppo": {"teacher_coef": 1e3}})
    terms = {"teacher_loss": 1.7, "value_loss": 3.0, "entropy": 1.7, "partner_loss": 0.0, "policy_loss": 0.1}
    assert suspect(config, terms).startswith("ppo.teacher_coef (here 1000)")
    assert suspect(config, {**terms, "entropy": math.nan}).startswith("ppo.ent_coef (here 0.005)")
    assert suspect(config, {**terms, "value_loss": math.inf, "policy_loss": math.nan}).startswith("ppo.lr")


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("ppo.teacher_coef=1e30", "ppo: teacher_coef must lie in [0, 1000], got 1e+30"),
        ("ppo.lr=5", "ppo: lr must lie in (0, 1], got 5"),
        ("ppo.adam_eps=0", "ppo: adam_eps must lie in (0, 1], got 0"),
        ("num_envs=100000000", "num_envs must lie in [1, 1,048,576], got 100,000,000"),
        ("num_envs=1048576 num_steps=64", "env steps per update is more than 16,777,216"),
        ("env.overcooked.delivery_reward=1e30", "env.overcooked.delivery_reward must lie in [-1e+06, 1e+06]"),
        ("env.generator.handover_share=0.35", "env.generator.handover_share would be ignored"),
        ("env.generator.pots=[1,2]", "and this run trains on env.levels='cramped_room'; drop it"),
    ],
)
def test_cec_train_refuses_a_setting_out_of_its_range_or_ignored_by_name(tmp_path, override, message):
    """Before: teacher_coef=1e30 trained with grad_norm=inf and exited 0; a generator setting on a fixed
    kitchen was silently unused."""
    done = _cec("train", "--config", str(_tiny_yaml(tmp_path)), *override.split(), "--quiet", timeout=120)
    assert done.returncode == 2, done.stderr[-3000:]
    assert message in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "runs").exists()


def test_a_generator_setting_is_refused_on_dual_destination(tmp_path):
    from cec.config import ConfigError, load_config
    from cec.training.config import TrainConfig

    with pytest.raises(ConfigError, match="env.generator.count_decay would be ignored.*Dual Destination"):
        load_config(
            TrainConfig,
            None,
            [
                "algorithm=ippo",
                "env.name=dual_destination",
                "env.levels=fixed",
                "env.generator.count_decay=0.9",
            ],
        )


# ---- a full disk during a resume (writes past RLIMIT_FSIZE fail as on a full disk: EFBIG, not ENOSPC) ------


def _cec_with_file_cap(max_bytes: int, *args: str) -> subprocess.CompletedProcess:
    """`cec ARGS` in a process whose writes past `max_bytes` in any file fail (SIGXFSZ ignored, so the write
    raises OSError), as writes to a full disk do; the cap is set in the child itself (no fork of this one)."""
    code = (
        "import resource, runpy, signal, sys; signal.signal(signal.SIGXFSZ, signal.SIG_IGN); "
        f"resource.setrlimit(resource.RLIMIT_FSIZE, ({max_bytes}, {max_bytes})); "
        f"sys.argv = ['cec', *{list(args)!r}]; runpy.run_module('apps.cli', run_name='__main__')"
    )
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300)


def test_a_resume_that_cannot_write_its_trimmed_metrics_leaves_them_as_they_were(run):
    """`metrics.jsonl` was rewritten in place: a full disk midway would have cut it."""
    shutil.rmtree(run / "checkpoints/update_000000002")  # row 2 must go: the files are rewritten
    before = {p.name: p.read_bytes() for p in run.glob("metrics.*")}
    done = _cec_with_file_cap(200, "train", "--resume", str(run), "--max-updates", "1", "--quiet")
    assert done.returncode == 2, done.stderr[-3000:]
    assert f"cannot write {run / 'metrics.jsonl'} (File too large); it was left as it was" in done.stderr
    assert {p.name: p.read_bytes() for p in run.glob("metrics.*")} == before
    assert not list(run.glob("*.tmp")) and "Traceback" not in done.stderr


def test_a_checkpoint_that_cannot_be_written_leaves_nothing_and_the_older_ones_as_they_were(run):
    shutil.rmtree(run / "checkpoints/update_000000002")
    state = (run / "checkpoints/update_000000001/state.msgpack").stat().st_size
    done = _cec_with_file_cap(state // 2, "train", "--resume", str(run), "--max-updates", "1", "--quiet")
    assert done.returncode == 2, done.stderr[-3000:]
    assert "cannot write checkpoint" in done.stderr and "update_000000002 (File too large)" in done.stderr
    assert "Traceback" not in done.stderr
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["update_000000001"]
    again = _cec("train", "--resume", str(run), "--max-updates", "1", "--quiet")  # room again: it goes on
    assert again.returncode == 0, again.stderr[-3000:]
    assert _updates(run) == ([1, 2], [1, 2])


def test_a_runs_rows_are_read_bounded_by_the_reproductions(tmp_path):
    """`cec reproduce` read a run's whole metrics.jsonl with read_text: /dev/zero or one endless line was
    read to MemoryError."""
    from apps.reproduce.pipeline import read_metrics
    from cec.training.metrics_file import LINE_MAX_BYTES, RunFileError

    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.jsonl").write_text('{"update": 1}\n{"update": 2}\n{"upd')  # a torn last line: left out
    assert read_metrics(run) == [{"update": 1}, {"update": 2}]
    (run / "metrics.jsonl").write_bytes(b"x" * (LINE_MAX_BYTES + 10))
    with pytest.raises(RunFileError, match="line 1: longer than 1,048,576 bytes"):
        read_metrics(run)
    (run / "metrics.jsonl").unlink()
    (run / "metrics.jsonl").symlink_to("/dev/zero")
    with pytest.raises(RunFileError, match="is not a regular file"):
        read_metrics(run)
