"""`cec train` in a subprocess: config errors, SIGINT/SIGTERM save a checkpoint, --resume finishes."""

import json
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[3]

QUICK = {
    "algorithm": "ippo",
    "num_envs": 4,
    "num_steps": 8,
    "total_env_steps": 4 * 8 * 400,
    "network": "small",
    "env": {"name": "dual_destination", "levels": "fixed", "dual_destination": {"max_steps": 8}},
    "checkpoint": {"every_updates": 0, "milestones": []},
    "name": "cli",
}


def _cec(*args, **kwargs):
    return subprocess.Popen(
        [sys.executable, "-m", "apps.cli", *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kwargs,
    )


def test_config_errors_exit_2_with_the_cause(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({**QUICK, "num_env": 3}))
    proc = _cec("train", "--config", str(bad))
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2
    assert "unknown key 'num_env'" in err and "did you mean 'num_envs'" in err
    proc = _cec("train", "--config", str(tmp_path / "missing.yaml"))
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2 and "does not exist" in err
    good = tmp_path / "good.yaml"
    good.write_text(yaml.safe_dump(QUICK))
    # within every size's range (those refusals are their own test), but the observations alone of one
    # update of Overcooked's 9x9x26 view would take hundreds of GiB
    huge = ["env.name=overcooked", "env.levels=cramped_room", "num_envs=1_048_576", "num_steps=16"]
    proc = _cec("train", "--config", str(good), f"run_dir={tmp_path / 'runs'}", *huge)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2 and "GiB" in err and "lower num_envs, num_steps or num_seeds" in err
    assert not (tmp_path / "runs").exists()  # refused before any work


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_saves_a_checkpoint_and_resume_finishes(tmp_path, sig):
    # A run far too long to finish before the signal arrives, however fast the machine or warm the compile
    # cache (400 updates used to finish first now and then); the resumed run then stops 5 updates later.
    cfg = tmp_path / "quick.yaml"
    cfg.write_text(
        yaml.safe_dump({**QUICK, "total_env_steps": 4 * 8 * 10**7, "run_dir": str(tmp_path / "runs")})
    )
    proc = _cec("train", "--config", str(cfg))
    assert proc.stderr is not None
    lines = (line for line in proc.stderr if line.startswith("update "))  # training under way
    first, second = next(lines), next(lines)
    proc.send_signal(sig)
    # the first update compiled: its line gives no ETA (it was hours, the compile's time x the updates left);
    # the next one times the pace since
    assert first.rstrip().endswith("| ETA ? (timed from the next update)"), first
    assert re.search(r"\| ETA \d+h\d\dm$|\| ETA \d+m\d\ds$", second.rstrip()), second
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "checkpoint saved" in err and "interrupted after" in out
    run = tmp_path / "runs" / "cli"
    meta = json.loads(next((run / "checkpoints").glob("update_*/meta.json")).read_text())
    stopped_at = meta["update"]
    assert stopped_at > 0

    proc = _cec("train", "--resume", str(run), "--quiet", "--max-updates", "5")
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert (
        f"resuming {run} from update {stopped_at}" in err
        and f"finished after {stopped_at + 5} updates" in out
    )
    updates = [json.loads(line)["update"] for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert updates == list(range(1, stopped_at + 6))


def test_resume_continues_a_moved_run_where_it_lies(tmp_path):
    cfg = tmp_path / "quick.yaml"
    cfg.write_text(yaml.safe_dump({**QUICK, "total_env_steps": 4 * 8 * 6, "run_dir": str(tmp_path / "runs")}))
    proc = _cec("train", "--config", str(cfg), "--max-updates", "3", "--quiet")
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    moved = tmp_path / "elsewhere" / "moved"
    moved.parent.mkdir()
    (tmp_path / "runs" / "cli").rename(moved)

    proc = _cec("train", "--resume", str(moved), "--quiet")
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert "continuing it where it is now" in err and f"resuming {moved} from update 3" in err
    assert "finished after 6 updates" in out
    assert not (tmp_path / "runs" / "cli").exists()  # nothing started at the old location
    updates = [json.loads(line)["update"] for line in (moved / "metrics.jsonl").read_text().splitlines()]
    assert updates == list(range(1, 7))


@pytest.mark.parametrize(
    "distributed",
    [False, pytest.param(True, marks=pytest.mark.slow)],  # the learner and its actor start: ~30 s
    ids=["cec-train", "learner-local-pool"],
)
def test_a_training_call_out_of_memory_is_one_line_naming_the_sizes(
    tmp_path, monkeypatch, capsys, distributed
):
    """What the check before compiling lets through (it counts observations only: Dual Destination at
    65,536 envs x 256 steps passes it and XLA then fails to allocate 32.9 GB) ends `cec train` with exit 2
    and the sizes to lower, not XLA's traceback; so does the distributed learner's update (what `cec up`
    runs: before, the learner's actor died with the traceback in its log)."""
    import jax

    from apps.cli import main
    from cec.training.trainer import Trainer
    from services.learner.learner import Learner

    def raise_exhausted(*args):
        raise jax.errors.JaxRuntimeError("RESOURCE_EXHAUSTED: Out of memory allocating 32906073832 bytes")

    monkeypatch.setattr(Trainer, "train_call", lambda self, n: raise_exhausted)
    monkeypatch.setattr(Learner, "_learn_fn", raise_exhausted)
    good = tmp_path / "good.yaml"
    good.write_text(yaml.safe_dump(QUICK))
    args = ["train", "--config", str(good), f"run_dir={tmp_path / 'runs'}", "--quiet"]
    if distributed:  # its actors in this process
        args += ["--distributed", "distributed.pool=local", "distributed.num_actors=1",
                 "distributed.publish_checkpoints=false", "distributed.metrics_port=0"]  # fmt: skip
    assert main(args) == 2
    err = capsys.readouterr().err
    what = "the learner's update" if distributed else "the training call"
    assert f"{what} does not fit in the memory" in err and "Out of memory allocating 32906073832 bytes" in err
    assert "num_envs 4 x num_steps 8" in err and "lower num_envs, num_steps or num_seeds" in err
    assert "Traceback" not in err
