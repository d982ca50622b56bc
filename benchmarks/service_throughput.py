"""The release recipe's env-steps/s through `cec up` (the whole service: level server, Ray actors, learner,
evaluator, Redis) against `cec train` (one process), on the same machine in the same run, and the
evaluator's share of the machine's CPU time while it trains.

    python benchmarks/service_throughput.py [--seeds 6] [--updates 30] [--every 10] [--out FILE.json]

Both run the release recipe (configs/up/release.yaml's training preset and seeds) for `--updates` updates,
as a user runs them (subprocesses of the `cec` command, the machine otherwise idle); throughput is the
median of the per-update env-steps/s of all seeds after the first `--skip` updates (compilation excluded).
`cec up` runs with its evaluator scoring a checkpoint every `--every` updates, as the release does; the
CPU time of every process of the stack is sampled each second (psutil, the process tree of `cec up`), and
the evaluator's share is its CPU seconds over all of the stack's between the first and the last update.
The ratio up / train is per core too: both use the same cores. Goal (issue 85): >= 0.8.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
PRESET = "configs/up/release.yaml"


def _rows(run: Path) -> list[dict]:
    path = run / "metrics.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def _median_sps(run: Path, skip: int) -> float:
    rows = _rows(run)
    per_update = {r["update"]: r["env_steps_per_s"] for r in rows if r["update"] > skip}
    return float(statistics.median(per_update.values()))


def _role(proc: object) -> str:
    import psutil

    try:
        cmd = " ".join(proc.cmdline())  # type: ignore[attr-defined]
    except psutil.Error:
        return "gone"
    for key, role in (("services.evaluator", "evaluator"), ("services.level_server", "level server"),
                      ("redis-server", "redis"), ("ray::", "ray workers"), ("raylet", "ray"), ("gcs", "ray"),
                      ("dashboard", "ray"), ("apps.cli", "driver")):  # fmt: skip
        if key in cmd:
            return role
    return "other"


def _sample(root: int, since: float, seen: dict[int, tuple[str, float]]) -> None:
    """Each process of the tree under `root`, and Ray's workers started since `since` (their raylet
    detaches them from the tree): its role and CPU seconds so far."""
    import psutil

    try:
        procs = [psutil.Process(root), *psutil.Process(root).children(recursive=True)]
    except psutil.Error:
        return
    for p in psutil.process_iter():
        try:
            if p.create_time() >= since and p.pid not in {q.pid for q in procs} and _role(p) == "ray workers":
                procs.append(p)
        except psutil.Error:
            continue
    for p in procs:
        try:
            t = p.cpu_times()
            seen[p.pid] = (seen.get(p.pid, (_role(p), 0.0))[0], t.user + t.system)
        except psutil.Error:
            continue


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--updates", type=int, default=30)
    ap.add_argument("--every", type=int, default=10, help="the evaluator's checkpoint interval under cec up")
    ap.add_argument("--skip", type=int, default=3, help="updates left out of the median (compilation)")
    ap.add_argument("--out", default="")
    args = ap.parse_args()

    from apps.machine import machine_info
    from cec.config import load_config
    from services.stack import UpConfig, preset_path

    up = load_config(UpConfig, preset_path(PRESET))
    train_cfg = up.train_config((f"num_seeds={args.seeds}",))
    overrides = [f"num_seeds={args.seeds}", "updates_per_call=1"]
    recipe = [o for o in up.train_overrides if not o.startswith(("num_seeds=", "name=", "checkpoint."))]
    tmp = Path(tempfile.mkdtemp(prefix="cec-service-bench-"))
    cec = [sys.executable, "-m", "apps.cli"]
    print(
        f"release recipe ({up.train}), {args.seeds} seeds x {train_cfg.steps_per_update} env steps per update"
    )

    t0 = time.perf_counter()
    subprocess.run([*cec, "train", "--config", up.train, "--quiet", "--max-updates", str(args.updates),
                    *overrides, *recipe, "checkpoint.every_updates=0", "checkpoint.milestones=[]",
                    f"run_dir={tmp}", "name=train"], cwd=REPO, check=True)  # fmt: skip
    train_sps = _median_sps(tmp / "train", args.skip)
    print(f"cec train: {train_sps:,.0f} env-steps/s ({time.perf_counter() - t0:.0f} s wall)", flush=True)

    cmd = [*cec, "up", "--config", PRESET, "--max-updates", str(args.updates), "level_server_port=0",
           "level_server_metrics_port=-1", "evaluator_metrics_port=-1", "distributed.metrics_port=-1",
           "ray_dashboard=false", *[f"train.{o}" for o in overrides], f"train.run_dir={tmp}", "train.name=up",
           f"train.checkpoint.every_updates={args.every}", "evaluator_drain_s=0"]  # fmt: skip
    log = open(tmp / "up.log", "w")  # noqa: SIM115
    t0 = time.perf_counter()
    since = time.time()
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=log, stderr=subprocess.STDOUT)
    seen: dict[int, tuple[str, float]] = {}
    start: dict[int, tuple[str, float]] | None = None
    while proc.poll() is None:
        _sample(proc.pid, since, seen)
        rows = _rows(tmp / "up")
        if start is None and rows and rows[-1]["update"] > args.skip:
            start = dict(seen)  # the window opens after the compiled first updates
        if rows and rows[-1]["update"] >= args.updates:
            break
        time.sleep(1.0)
    end = dict(seen)
    proc.wait(600)
    log.close()
    up_sps = _median_sps(tmp / "up", args.skip)
    spent: dict[str, float] = {}
    for pid, (role, cpu) in end.items():
        spent[role] = spent.get(role, 0.0) + cpu - (start or {}).get(pid, (role, 0.0))[1]
    total = sum(spent.values())
    share = spent.get("evaluator", 0.0) / total if total else float("nan")
    print(f"cec up:    {up_sps:,.0f} env-steps/s ({time.perf_counter() - t0:.0f} s wall)")
    roles = ", ".join(f"{k} {v:.0f}" for k, v in sorted(spent.items(), key=lambda kv: -kv[1]))
    print(f"ratio up / train: {up_sps / train_sps:.2f} (goal >= 0.8); the evaluator's share of the stack's "
          f"CPU time while training: {100 * share:.0f}%; CPU seconds by role: {roles}")  # fmt: skip
    if args.out:
        result = {
            "benchmark": "service_throughput", "preset": PRESET, "seeds": args.seeds, "updates": args.updates,
            "evaluator_every_updates": args.every, "machine": machine_info(load_average=True),
            "cec_train_env_steps_per_s": round(train_sps, 1), "cec_up_env_steps_per_s": round(up_sps, 1),
            "ratio": round(up_sps / train_sps, 3), "evaluator_cpu_share": round(share, 3),
            "cpu_seconds_by_role": {k: round(v, 1) for k, v in spent.items()},
        }  # fmt: skip
        Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
