"""Throughput of the data-parallel trainer over N local devices (`devices=N`), against one device (the peer)
measured in the same run.

Each N runs in its own process (JAX fixes its devices when it starts); on a CPU the N devices are fake
(`XLA_FLAGS=--xla_force_host_platform_device_count=N`) and share the machine's cores, so the figure there is
the cost of the partitioning (its collectives and per-device dispatch), not a speed-up: the speed-up needs N
real devices (GPUs). For each N: compile time, then env-steps/s of the compiled training call (median of
`--repeats` calls of `--updates` updates each), and the ratio to N = 1.

    python benchmarks/data_parallel.py                     # N = 1, 2, 4 on this machine's devices
    python benchmarks/data_parallel.py --devices 1 8 --config configs/train/cec_overcooked.yaml
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

try:  # run as a script (benchmarks/ on sys.path) or as a module
    from env_throughput import git_rev, machine  # type: ignore[import-not-found]
    from train_throughput import time_train_call  # type: ignore[import-not-found]
except ImportError:
    from benchmarks.env_throughput import git_rev, machine
    from benchmarks.train_throughput import time_train_call

RESULTS = Path(__file__).parent / "results"
REPO = Path(__file__).resolve().parents[1]


def measure(config: str, overrides: list[str], devices: int, updates: int, repeats: int) -> dict:
    """In this process: compile, then time the training call on `devices` devices."""
    import jax

    from cec.config import load_config
    from cec.training.config import TrainConfig
    from cec.training.trainer import Trainer

    cfg = load_config(TrainConfig, config, [*overrides, f"devices={devices}", f"updates_per_call={updates}"])
    first, times = time_train_call(Trainer(cfg), updates, repeats)
    median = statistics.median(times)
    steps = updates * cfg.steps_per_update * cfg.num_seeds
    return {
        "devices": devices,
        "device_kind": jax.local_devices()[0].device_kind,
        "compile_s": round(first - median, 2),
        "call_s": round(median, 4),
        "env_steps_per_s": round(steps / median, 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--devices", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--config", default="configs/train/cec_overcooked_cpu.yaml")
    ap.add_argument(
        "--overrides", nargs="*", default=["num_envs=64", "num_steps=128", "ppo.num_minibatches=4"]
    )
    ap.add_argument("--updates", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(RESULTS / "data_parallel_cpu_2cpu.json"))
    ap.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        print(json.dumps(measure(args.config, args.overrides, args.child, args.updates, args.repeats)))
        return 0
    rows = []
    for n in args.devices:
        env = dict(os.environ)
        if "cuda" not in env.get("JAX_PLATFORMS", "") and not _has_gpu():
            env["XLA_FLAGS"] = (
                f"{env.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={n}".strip()
            )
        cmd = [sys.executable, __file__, "--child", str(n), "--config", args.config, "--updates",
               str(args.updates), "--repeats", str(args.repeats), "--overrides", *args.overrides]  # fmt: skip
        print(f"devices={n}: compiling and timing...", file=sys.stderr, flush=True)
        proc = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, check=False)
        if proc.returncode:
            print(proc.stderr[-3000:], file=sys.stderr)
            return proc.returncode
        row = json.loads(proc.stdout.strip().splitlines()[-1])
        row["ratio_to_one_device"] = (
            round(row["env_steps_per_s"] / rows[0]["env_steps_per_s"], 3) if rows else 1.0
        )
        rows.append(row)
        print(f"devices={n} ({row['device_kind']}): {row['env_steps_per_s']:,.0f} env-steps/s, compile "
              f"{row['compile_s']} s, x{row['ratio_to_one_device']} of one device")  # fmt: skip
    result = {
        "benchmark": "data_parallel", "date": datetime.date.today().isoformat(), "commit": git_rev(),
        "machine": machine(), "config": args.config, "overrides": args.overrides, "updates": args.updates,
        "repeats": args.repeats, "rows": rows,
    }  # fmt: skip
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


def _has_gpu() -> bool:
    """Whether this machine has an NVIDIA GPU (then the devices are real, not fake CPU ones)."""
    return Path("/dev/nvidia0").exists()


if __name__ == "__main__":
    raise SystemExit(main())
