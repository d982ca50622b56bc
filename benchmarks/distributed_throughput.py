"""Env-steps/s of the distributed trainer (Ray actors + learner) vs the single-process trainer, same run.

    python benchmarks/distributed_throughput.py [--preset configs/train/cramped_room_ci.yaml]
        [--actors 1 2 4] [--modes sync async] [--updates 12] [--out benchmarks/results/X.json]

For each configuration: the single-process trainer (`cec train`, one jitted call per update) and the Ray
learner with 1, 2 and 4 actors in each mode, on the same network, envs and steps per update. Throughput is
the median of the per-update env-steps/s after the first two updates (compilation excluded). The learner's
own Prometheus counters give the time per stage (rollout inside actors, transfer, update, publish, wait) and
the bytes shipped per agent-step, compared with the raw observation size.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _median_sps(run_dir: Path, skip: int = 2) -> float:
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    return float(statistics.median(r["env_steps_per_s"] for r in rows[skip:]))


def _counter(metric: object, label: str | None = None) -> float:
    m = metric.labels(label) if label is not None else metric  # type: ignore[attr-defined]
    return float(m._value.get())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default=str(REPO / "configs/train/cramped_room_ci.yaml"))
    parser.add_argument("--actors", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--modes", nargs="+", default=["sync", "async"])
    parser.add_argument("--updates", type=int, default=12)
    parser.add_argument("--out", default="")
    parser.add_argument("overrides", nargs="*", help="training preset overrides")
    args = parser.parse_args()

    import numpy as np
    import ray

    from apps.machine import machine_info
    from cec.config import load_config
    from cec.training.config import TrainConfig
    from cec.training.run import train
    from cec.training.trainer import Trainer
    from services import metrics as M  # noqa: N812
    from services.learner.config import DistributedConfig
    from services.learner.learner import Learner
    from services.learner.ray_pool import RayPool

    tmp = Path(tempfile.mkdtemp(prefix="cec-dist-bench-"))
    base = [*args.overrides, "updates_per_call=1", f"run_dir={tmp}", "checkpoint.every_updates=0",
            "checkpoint.milestones=[]"]  # fmt: skip
    probe = load_config(TrainConfig, args.preset, base)
    total = probe.steps_per_update * args.updates
    base.append(f"total_env_steps={total}")
    obs_bytes = int(np.prod(Trainer(probe).task.obs_shape)) * (1 if probe.env.name == "overcooked" else 4)
    results: dict = {
        "preset": args.preset,
        "overrides": args.overrides,
        "num_envs": probe.num_envs,
        "num_steps": probe.num_steps,
        "updates": args.updates,
        "machine": machine_info(load_average=True),
        "raw_obs_bytes_per_agent_step": obs_bytes,
        "runs": [],
    }
    print(
        f"{args.preset}: {probe.num_envs} envs x {probe.num_steps} steps per update, {args.updates} updates"
    )

    t0 = time.perf_counter()
    train(load_config(TrainConfig, args.preset, [*base, "name=single"]), progress=False)
    single = _median_sps(tmp / "single")
    print(f"single process: {single:,.0f} env-steps/s ({time.perf_counter() - t0:.0f} s wall)", flush=True)
    results["single_process_env_steps_per_s"] = single

    ray.init(
        address="local",  # a Ray of its own, whatever other cluster this machine runs or last ran
        num_cpus=max(os.cpu_count() or 1, max(args.actors)),
        include_dashboard=False,
        logging_level="ERROR",
    )
    stages = ("rollout", "transfer", "update", "publish", "checkpoint", "wait")
    for mode in args.modes:
        for n in args.actors:
            if probe.num_envs % n:
                continue
            name = f"{mode}-{n}"
            before = {s: _counter(M.LEARNER_STAGE_SECONDS, s) for s in stages}
            b0, a0 = _counter(M.LEARNER_BYTES_RECEIVED), _counter(M.LEARNER_AGENT_STEPS_RECEIVED)
            cfg = load_config(TrainConfig, args.preset, [*base, f"name={name}"])
            t0 = time.perf_counter()
            dist = DistributedConfig(num_actors=n, mode=mode, metrics_port=-1)
            Learner(cfg, dist, pool=RayPool(dist)).run(resume=False)
            wall = time.perf_counter() - t0
            sps = _median_sps(tmp / name)
            spent = {s: round(_counter(M.LEARNER_STAGE_SECONDS, s) - before[s], 3) for s in stages}
            per_step = (_counter(M.LEARNER_BYTES_RECEIVED) - b0) / max(
                1.0, _counter(M.LEARNER_AGENT_STEPS_RECEIVED) - a0
            )
            run = {
                "mode": mode,
                "actors": n,
                "env_steps_per_s": round(sps, 1),
                "ratio_to_single_process": round(sps / single, 3),
                "stage_seconds": spent,
                "bytes_per_agent_step": round(per_step, 1),
                "bytes_ratio_to_raw_obs": round(per_step / obs_bytes, 4),
                "wall_s": round(wall, 1),
            }
            results["runs"].append(run)
            print(
                f"{mode:5s} {n} actor(s): {sps:,.0f} env-steps/s = {sps / single:.2f}x single | "
                f"{per_step:.0f} B/agent-step = {100 * per_step / obs_bytes:.1f}% of raw obs | {spent}",
                flush=True,
            )
    ray.shutdown()
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
