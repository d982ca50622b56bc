"""`benchmarks/time_to_skill.py`: a recipe costs its training time, not the time its process was stopped."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest

from tests.scripts import benchmark


def _module() -> Any:
    return benchmark("time_to_skill")


def test_a_stopped_update_counts_at_the_runs_median_rate_and_a_slow_one_as_measured(
    saved_run: tuple[Path, Path, Any], tmp_path: Path
) -> None:
    tts = _module()
    run = tmp_path / "r"
    shutil.copytree(saved_run[0], run)  # two seeds
    rates = [1000.0, 1000.0, 400.0, 1000.0, 10.0]  # update 3 shared the core; update 5 was stopped
    lines = ["update,seed,env_steps,env_steps_per_s"]
    for u, rate in enumerate(rates, start=1):
        lines += [f"{u},{seed},{u * 500},{rate}" for seed in (4, 5)]
    (run / "metrics.csv").write_text("\n".join(lines) + "\n")
    seconds, stalled = tts.training_seconds(run)
    assert stalled == 1
    # each update: 500 steps per seed x 2 seeds at the rate of all seeds; the stopped one at the median
    assert seconds[3] == pytest.approx(1.0 + 1.0 + 2.5)
    assert seconds[5] == pytest.approx(seconds[4] + 1.0)


def test_checkpoints_already_evaluated_are_not_played_again(
    saved_run: tuple[Path, Path, Any], tmp_path: Path
) -> None:
    tts = _module()
    run = tmp_path / "r"
    shutil.copytree(saved_run[0], run)  # one checkpoint, update 0
    (run / "metrics.csv").write_text("update,seed,env_steps,env_steps_per_s\n1,4,16,100.0\n1,5,16,100.0\n")
    assert tts.evaluate([run], 1, done=frozenset({("r", 0)})) == []  # no cross-play compiled, none played


def test_a_checkpoint_its_running_run_removed_is_skipped_and_a_corrupt_one_refused(
    saved_run: tuple[Path, Path, Any], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Evaluating a run while it trains: the run replaces its latest checkpoint (keep_last) while the
    milestones before it are played; that one is skipped. One still there but unreadable is refused."""
    from cec.checkpoints import CorruptCheckpointError

    tts = _module()
    run = tmp_path / "r"
    shutil.copytree(saved_run[0], run)
    (run / "metrics.csv").write_text("update,seed,env_steps,env_steps_per_s\n1,4,16,100.0\n1,5,16,100.0\n")

    def pruned(name, checkpoints, levels, config):
        for c in checkpoints:
            (c / "meta.json").unlink()  # the trainer's prune, caught half-way
        raise CorruptCheckpointError(f"{checkpoints[0]} is not a checkpoint: meta.json is missing")

    monkeypatch.setattr(tts, "play_milestone", pruned)
    assert tts.evaluate([run], 1) == []

    shutil.rmtree(run)
    shutil.copytree(saved_run[0], run)
    (run / "metrics.csv").write_text("update,seed,env_steps,env_steps_per_s\n1,4,16,100.0\n1,5,16,100.0\n")

    def corrupt(name, checkpoints, levels, config):
        raise CorruptCheckpointError("state.msgpack: checksum mismatch")

    monkeypatch.setattr(tts, "play_milestone", corrupt)
    with pytest.raises(CorruptCheckpointError, match="checksum"):
        tts.evaluate([run], 1)


def test_joined_runs_must_be_one_recipe_and_are_evaluated_as_one(
    saved_run: tuple[Path, Path, Any], tmp_path: Path
) -> None:
    """`--join`: seeds trained in separate processes are one population only if their recipes agree."""
    tts = _module()
    runs = [tmp_path / "a", tmp_path / "b"]
    for run, (seed, envs) in zip(runs, ((4, 64), (6, 32)), strict=True):
        shutil.copytree(saved_run[0], run)
        (run / "metrics.csv").write_text("update,seed,env_steps,env_steps_per_s\n1,4,16,100.0\n")
        (run / "config.yaml").write_text(f"seed: {seed}\nname: {run.name}\nnum_envs: {envs}\n")
    with pytest.raises(SystemExit, match="differ in more than seed and name"):
        tts.evaluate(runs, 1, name="ab")
    (runs[1] / "config.yaml").write_text("seed: 6\nname: b\nnum_envs: 64\n")
    assert tts.evaluate(runs, 1, done=frozenset({("ab", 0)}), name="ab") == []  # joined under its name


def test_join_refuses_a_run_given_twice_and_runs_that_share_a_seed(tmp_path: Path) -> None:
    """Two runs of the same seeds, or one run twice, joined as one population would count a seed playing
    itself as cross-play: refused before anything is played, naming the run or the seed."""
    tts = _module()
    runs = {name: tmp_path / name for name in ("a", "b", "c")}
    for name, (seed, seeds) in zip(runs, ((4, 2), (5, 2), (6, 2)), strict=True):
        runs[name].mkdir()
        (runs[name] / "config.yaml").write_text(
            f"seed: {seed}\nnum_seeds: {seeds}\nname: {name}\nnum_envs: 8\n"
        )
        (runs[name] / "metrics.csv").write_text("update,seed,env_steps,env_steps_per_s\n")
    out = ["--out", str(tmp_path / "tts")]
    twice = [str(runs["a"]), str(tmp_path / "b" / ".." / "a")]  # one run, spelled twice
    with pytest.raises(SystemExit, match=r"ab: .*a is given twice \(as .*a too\)"):
        tts.main(["--join", "ab", *twice, *out])
    with pytest.raises(SystemExit, match=r"ab: seed 5 is trained by both .*a and .*b: joined runs must be"):
        tts.main(["--join", "ab", str(runs["a"]), str(runs["b"]), *out])
    tts.check_population([runs["a"], runs["c"]], "ac")  # seeds 4-5 and 6-7: one population of four
    # runs continuing each its own seed's checkpoint of one recipe are one population; of two recipes not
    late = {}
    for name, source, seed in (("la", "a", 4), ("lc", "c", 6)):
        late[name] = tmp_path / name
        late[name].mkdir()
        start = runs[source] / "checkpoints" / "update_000000640"
        (late[name] / "config.yaml").write_text(f"seed: {seed}\nname: {name}\ninit_from: {start}\n")
    tts.check_population([late["la"], late["lc"]], "late")
    (runs["c"] / "config.yaml").write_text("seed: 6\nnum_seeds: 2\nname: c\nnum_envs: 16\n")
    with pytest.raises(SystemExit, match="differ in more than seed and name"):
        tts.check_population([late["la"], late["lc"]], "late")
    assert not (tmp_path / "tts.json").exists()


def test_a_setting_added_since_a_run_started_counts_as_its_default_when_joining(tmp_path: Path) -> None:
    """A run begun before a lever existed and one begun after, with the lever off, are one recipe; with the
    lever on they are not."""
    tts = _module()
    old, new = tmp_path / "old", tmp_path / "new"
    for run in (old, new):
        run.mkdir()
    (old / "config.yaml").write_text("seed: 4\nname: old\nnum_envs: 8\n")
    lever = "seed: 5\nname: new\nnum_envs: 8\nenv:\n  overcooked:\n    pass_reward: {}\n"
    (new / "config.yaml").write_text(lever.format(0.0))
    tts.check_population([old, new], "joined")
    (new / "config.yaml").write_text(lever.format(2.0))
    with pytest.raises(SystemExit, match="differ in more than seed and name"):
        tts.check_population([old, new], "joined")


def test_a_path_that_is_no_run_is_refused_before_anything_is_played(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A brace list that `sh` does not expand (`runs/x-s40{0,1}`) or a mistyped directory: named, with the
    fix, before any checkpoint is compiled or played (it used to end in a traceback after the others)."""
    tts = _module()
    real = tmp_path / "x-s400"
    real.mkdir()
    (real / "metrics.csv").write_text("update,seed,env_steps,env_steps_per_s\n")
    with pytest.raises(SystemExit):
        tts.main(["--join", "x", str(real), str(tmp_path / "x-s40{1,2}"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert "not a training run (no metrics.csv): " in err and "x-s40{1,2}" in err and "x-s400," not in err
    assert not (tmp_path / "o.json").exists()
