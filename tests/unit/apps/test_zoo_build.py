"""`cec zoo build`: a tiny Dual Destination zoo (2 IPPO seeds, 1 FCP seed on them), skip/resume, bad specs."""

from __future__ import annotations

import io
import re
import shutil
from pathlib import Path

import jax
import numpy as np
import pytest
import yaml

from apps.zoo_build import build_zoo, export_zoo, plan_zoo
from cec import checkpoints
from cec.agents.policy import load_policies, load_policy
from cec.agents.zoo import load_zoo
from cec.config import ConfigError
from cec.training import run as training_run

PRESETS = Path(__file__).resolve().parents[3] / "configs" / "train"
TINY = ["num_envs=8", "num_steps=10", "total_env_steps=160", "updates_per_call=1"]  # 2 updates, one per call


def _spec(tmp_path: Path, entries: list[dict], name: str = "spec.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump({"entries": entries}))
    return path


def _tiny_zoo_spec(tmp_path: Path) -> Path:
    return _spec(
        tmp_path,
        [
            {
                "preset": str(PRESETS / "dd_ippo_quick.yaml"),
                "seeds": [0, 1],
                "overrides": [*TINY, "checkpoint.milestones=[0.0, 0.5, 1.0]"],
            },
            {"preset": str(PRESETS / "dd_fcp_quick.yaml"), "seeds": [0], "overrides": TINY},
        ],
    )


@pytest.fixture(scope="module")
def zoo(tmp_path_factory):
    """The built zoo: (spec, zoo dir, build log)."""
    tmp = tmp_path_factory.mktemp("zoo")
    spec, out, log = _tiny_zoo_spec(tmp), tmp / "zoo", io.StringIO()
    result = build_zoo(spec, out, log=log)
    assert not result.interrupted and result.trained == (
        "ippo-dual_destination-fixed-s0",
        "fcp-dual_destination-fixed-s0",
    )
    return spec, out, log.getvalue()


def test_build_writes_a_manifest_of_final_checkpoints(zoo):
    spec, out, log = zoo
    assert "[1/2] ippo-dual_destination-fixed-s0" in log and "[2/2] fcp-dual_destination-fixed-s0" in log
    raw = yaml.safe_load((out / "zoo.yaml").read_text())["policies"]
    assert [(p["name"], p["algorithm"], p["seed"]) for p in raw] == [
        ("ippo-dual_destination-fixed-s0", "ippo", 0),
        ("ippo-dual_destination-fixed-s1", "ippo", 1),
        ("fcp-dual_destination-fixed-s0", "fcp", 0),
    ]
    for p in raw:
        assert (p["env"], p["layout"], p["env_steps"]) == ("dual_destination", "fixed", 160)
        assert "levels" not in p  # only single-kitchen Overcooked agents are restricted
        ckpt = out / p["checkpoint"]
        meta = checkpoints.read_meta(ckpt)
        assert meta["update"] == 2 and p["sha256"] == meta["sha256"]
    # the FCP learner trained with the zoo's own IPPO run (re-rooted population: 2 seeds x 3 milestones)
    fcp_meta = checkpoints.read_meta(out / raw[2]["checkpoint"])
    (population,) = fcp_meta["config"]["partner"]["population"]
    assert Path(population["run"]) == (out / "runs/ippo-dual_destination-fixed-s0").resolve()
    # the manifest loads as a zoo, and every entry loads as a policy
    entries = load_zoo(out / "zoo.yaml")
    policies, skipped = load_policies(entries)
    assert not skipped and [p.algorithm for p in policies] == ["ippo", "ippo", "fcp"]
    assert load_policy(entries[1]).seed == 1


def test_export_writes_one_seed_parameter_checkpoints_that_play_as_the_originals(zoo, tmp_path):
    _, out, _ = zoo
    shipped = tmp_path / "shipped"
    path = export_zoo(out / "zoo.yaml", shipped, names=["ippo-dual_destination-fixed-s1"], prefix="x_")
    described = "# What these are:\n#\n# where they came from.\n"  # a person's note on the folder's policies
    path.write_text(described + path.read_text().split("\n", 1)[1])
    export_zoo(out / "zoo.yaml", shipped, names=["fcp-dual_destination-fixed-s0"])  # collected, not replaced
    assert path.read_text().startswith(described + "policies:")  # the note stays
    raw = yaml.safe_load(path.read_text())["policies"]
    assert [(p["name"], p["algorithm"], p["seed"]) for p in raw] == [
        ("x_ippo-dual_destination-fixed-s1", "ippo", 1),
        ("fcp-dual_destination-fixed-s0", "fcp", 0),
    ]
    originals = {p.name: p for p in load_policies(load_zoo(out / "zoo.yaml"))[0]}
    exported, skipped = load_policies(load_zoo(path))
    assert not skipped
    sources = ["ippo-dual_destination-fixed-s1", "fcp-dual_destination-fixed-s0"]
    for policy, source in zip(exported, sources, strict=True):
        original = originals[source]
        assert (policy.seed, policy.network, policy.env) == (original.seed, original.network, original.env)
        for a, b in zip(jax.tree.leaves(policy.params), jax.tree.leaves(original.params), strict=True):
            np.testing.assert_array_equal(a, b)
        size = sum(f.stat().st_size for f in (shipped / raw[exported.index(policy)]["checkpoint"]).iterdir())
        assert size < sum(f.stat().st_size for f in Path(load_zoo(out / "zoo.yaml")[0].checkpoint).iterdir())
    with pytest.raises(ConfigError, match=r"no entries named \['nope'\]"):
        export_zoo(out / "zoo.yaml", shipped, names=["nope"])


def test_builds_side_by_side_share_the_runs(zoo, tmp_path, monkeypatch):
    """A run another process holds is passed over, a run reading it waits, and the build goes on once the
    other process is done (here: the IPPO run is held; its holder finishes it while this build waits)."""
    from apps import zoo_build

    spec, built, _ = zoo
    out = tmp_path / "zoo"
    shutil.copytree(built, out)
    (out / "zoo.yaml").unlink()
    ippo, fcp = out / "runs/ippo-dual_destination-fixed-s0", out / "runs/fcp-dual_destination-fixed-s0"
    finals = {run: run / "checkpoints/update_000000002" for run in (ippo, fcp)}
    for final in finals.values():
        shutil.rmtree(final)
    holder = checkpoints.RunLock(ippo).acquire()  # "another process" trains the IPPO run

    # the real trainer refuses a held run, naming the holder
    cfg = next(r.config for r in plan_zoo(spec, out) if r.run_dir == ippo)
    with pytest.raises(checkpoints.RunBusyError, match=r"being trained by another process \(pid \d+\)"):
        training_run.train(cfg, resume=True, log=io.StringIO())

    trained, waits = [], []

    def fake_train(config, *, resume, progress, log):  # locks the run as the real one does
        with checkpoints.RunLock(Path(config.run_dir) / config.run_name):
            trained.append(config.run_name)
            shutil.copytree(built / "runs" / fcp.name / finals[fcp].relative_to(fcp), finals[fcp])
        return training_run.RunResult(None, fcp, 2, interrupted=False)

    def other_process_finishes(seconds):
        waits.append(seconds)
        shutil.copytree(built / "runs" / ippo.name / finals[ippo].relative_to(ippo), finals[ippo])
        holder.release()

    monkeypatch.setattr(training_run, "train", fake_train)
    # not waiting (a process with other zoos to build): it names the runs left to the others and returns
    monkeypatch.setattr(zoo_build.time, "sleep", lambda s: pytest.fail("slept without wait"))
    early = build_zoo(spec, out, log=io.StringIO(), wait=False)
    assert early.manifest is None and not early.interrupted and early.left == (ippo.name, fcp.name)
    assert trained == [] and not (out / "zoo.yaml").exists()

    monkeypatch.setattr(zoo_build.time, "sleep", other_process_finishes)
    log = io.StringIO()
    result = build_zoo(spec, out, log=log, poll_s=7)
    text = log.getvalue()
    assert "ippo-dual_destination-fixed-s0 is trained elsewhere" in text
    assert not re.search(r"ippo-dual_destination-fixed-s0 \(.*\): (training|resuming)", text)  # not its own
    assert "fcp-dual_destination-fixed-s0 waits for ippo-dual_destination-fixed-s0" in text
    assert waits == [7] and trained == [fcp.name]
    assert result.manifest == out / "zoo.yaml" and result.skipped == (ippo.name,)


def test_second_build_skips_finished_runs_and_resumes_interrupted_ones(zoo, tmp_path, monkeypatch):
    spec, built, _ = zoo
    out = tmp_path / "zoo"  # a copy: the other tests read the built zoo
    shutil.copytree(built, out)
    log = io.StringIO()
    result = build_zoo(spec, out, log=log)
    assert result.trained == () and len(result.skipped) == 2 and "finished, skipping" in log.getvalue()

    # an interrupted IPPO run (its final checkpoint gone) is resumed from its latest, not restarted
    copy = tmp_path / "copy"
    run = out / "runs/ippo-dual_destination-fixed-s0"
    final = run / "checkpoints/update_000000002"
    shutil.copytree(out, copy)
    shutil.rmtree(final)
    calls = []

    def fake_train(config, *, resume, progress, log):
        calls.append((config.run_name, resume))
        shutil.copytree(copy / final.relative_to(out), final)  # "finish" the run
        return training_run.RunResult(None, run, 2, interrupted=False)

    monkeypatch.setattr(training_run, "train", fake_train)
    log = io.StringIO()
    result = build_zoo(spec, out, log=log)
    assert calls == [("ippo-dual_destination-fixed-s0", True)] and "resuming at update 1/2" in log.getvalue()
    assert result.manifest == out / "zoo.yaml"

    # an interruption stops the build without a manifest; the next build continues
    (out / "zoo.yaml").unlink()
    shutil.rmtree(final)
    monkeypatch.setattr(
        training_run, "train", lambda config, **kw: training_run.RunResult(None, run, 1, True)
    )
    result = build_zoo(spec, out, log=io.StringIO())
    assert result.interrupted and result.manifest is None and not (out / "zoo.yaml").exists()


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"preset": "configs/train/nope.yaml"}, "entries[0] (configs/train/nope.yaml): preset file"),
        ({"preset": "dd_ippo_quick.yaml", "overrides": ["num_env=3"]}, "did you mean 'num_envs'"),
        ({"preset": "dd_ippo_quick.yaml", "overrides": ["nokey"]}, "not of the form key=value"),
        ({"preset": "dd_ippo_quick.yaml", "seed": [0]}, "unknown key(s) ['seed']"),
        ({"preset": "dd_ippo_quick.yaml", "overrides": ["seed=3"]}, "use the entry's `seeds`"),
        ({"preset": "dd_ippo_quick.yaml", "seeds": [1, 1]}, "distinct integers"),
        ({"preset": "dd_ippo_quick.yaml", "label": ""}, "`label` must be a non-empty string"),
        ({"preset": "dd_fcp_quick.yaml"}, "partner.population run"),
    ],
)
def test_bad_specs_fail_before_any_training(tmp_path, monkeypatch, entry, message):
    monkeypatch.chdir(PRESETS)  # presets relative to the current directory
    monkeypatch.setattr(training_run, "train", lambda *a, **k: pytest.fail("trained despite a bad spec"))
    with pytest.raises(ConfigError) as info:
        build_zoo(_spec(tmp_path, [entry]), tmp_path / "zoo", log=io.StringIO())
    assert message in str(info.value), str(info.value)


def test_plan_checks_names_and_order(tmp_path):
    ippo = {"preset": str(PRESETS / "dd_ippo_quick.yaml")}
    with pytest.raises(ConfigError, match="both train run ippo-dual_destination-fixed-s0"):
        plan_zoo(_spec(tmp_path, [ippo, ippo]), tmp_path / "zoo")
    fcp = {"preset": str(PRESETS / "dd_fcp_quick.yaml")}
    with pytest.raises(ConfigError, match="trains later; move that entry before it"):
        plan_zoo(_spec(tmp_path, [fcp, ippo]), tmp_path / "zoo")
    pop = "partner.population=[{run: runs/ippo-dual_destination-fixed-s0, seeds: [5]}]"
    with pytest.raises(ConfigError, match=r"needs seeds \[5\], but entries\[0\]"):
        plan_zoo(_spec(tmp_path, [{**ippo, "seeds": [0, 1]}, {**fcp, "overrides": [pop]}]), tmp_path / "zoo")
    # non-consecutive seeds: one run per seed; a `name` renames runs and policies, a `label` relabels the
    # policies' algorithm (an ablation reported apart), which is otherwise the preset's
    entries = [{**ippo, "seeds": [4, 2], "name": "short", "label": "ippo_ablation"}, {**ippo, "seeds": [0]}]
    plan = plan_zoo(_spec(tmp_path, entries), tmp_path / "zoo")
    assert [(r.config.run_name, r.seeds, r.policy_names, r.algorithm) for r in plan] == [
        ("short-s2", (2,), ("short-s2",), "ippo_ablation"),
        ("short-s4", (4,), ("short-s4",), "ippo_ablation"),
        ("ippo-dual_destination-fixed-s0", (0,), ("ippo-dual_destination-fixed-s0",), "ippo"),
    ]
    assert {r.config.algorithm for r in plan} == {"ippo"}


def test_a_zoo_moved_as_a_whole_is_found_finished(zoo, tmp_path):
    # a zoo committed with the repository and checked out elsewhere: its FCP run names its population by
    # the old absolute path, which is the same run under the zoo's new place
    spec, out, _ = zoo
    moved = tmp_path / "elsewhere" / "zoo"
    shutil.copytree(out, moved)
    (moved / "zoo.yaml").unlink()
    result = build_zoo(spec, moved, log=io.StringIO())
    assert result.trained == () and len(result.skipped) == 2 and result.manifest == moved / "zoo.yaml"


def test_a_changed_spec_is_refused_before_training(zoo, tmp_path):
    spec, out, _ = zoo
    entries = yaml.safe_load(spec.read_text())["entries"]
    entries[1]["overrides"] = [*entries[1]["overrides"], "ppo.lr=0.002"]
    with pytest.raises(ConfigError, match="fcp-dual_destination-fixed-s0 was trained with another config"):
        plan_zoo(_spec(tmp_path, entries), out)


def test_cli_reports_a_bad_spec_with_exit_status_2(tmp_path, capsys):
    from apps.cli import main

    spec = _spec(tmp_path, [{"preset": str(PRESETS / "dd_ippo_quick.yaml"), "overrides": ["run_dir=x"]}])
    assert main(["zoo", "build", str(spec), "--out", str(tmp_path / "zoo")]) == 2
    err = capsys.readouterr().err
    assert "cec zoo: config error:" in err and "entries[0]" in err and "use --out" in err
