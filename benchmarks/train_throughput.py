"""Training throughput of the single-process trainer (rollout + PPO update), against the CPU's matmul peak
and against the paper authors' own training script, measured in the same run.

For each network preset and batch size (envs x steps per rollout), in CEC mode (procedural kitchens from the
generator, held-out set excluded, levels drawn every update):

* compile time of the trainer's call (its first call's time beyond the median timed one), reported apart;
* env-steps/s of the compiled call (median of `--repeats` timed calls of `--updates` updates each);
* FLOPs per env-step from XLA's cost analysis: the network's forward on one step (rollout) plus forward
  and backward of the PPO loss on one step (update), per seat; per env-step = 2 seats x (forward +
  epochs x forward-backward). Achieved FLOP/s = env-steps/s x FLOPs per env-step, as a fraction of the
  peak of a large jitted float32 matmul measured in this run.

With `--reference-repo` (a checkout of KJha02/crossEnvCooperation) and `--reference-python` (a venv with
their pinned stack, see benchmarks/peers/reference_train.py), their `ippo_general.py` runs in CEC mode at
`--reference-batch`, and our `reference` preset (their network: FC 256 + LSTM 128, no CNN) runs at the same
batch; the ratio is printed. Their CEC program takes about 20+ minutes to compile on a 2-core CPU.

    python benchmarks/train_throughput.py                         # paper + small + reference, CPU sizes
    python benchmarks/train_throughput.py --reference-repo /tmp/refcheckout \\
        --reference-python /tmp/refvenv/bin/python
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from cec.config import from_dict
from cec.training.config import TrainConfig
from cec.training.ppo import Batch, ppo_loss
from cec.training.trainer import Trainer

try:  # run as a script (benchmarks/ on sys.path) or as a module
    from env_throughput import save_result  # type: ignore[import-not-found]
except ImportError:
    from benchmarks.env_throughput import save_result

PEER = Path(__file__).parent / "peers" / "reference_train.py"


def time_train_call(trainer: Trainer, updates: int, repeats: int) -> tuple[float, list[float]]:
    """(seconds of the first call: compile + one call, seconds of each of `repeats` more calls) of the
    trainer's own compiled call of `updates` updates (state donated, as in `cec train`)."""
    state = trainer.init()
    call = trainer.train_call(updates)
    times = []
    for _ in range(repeats + 1):
        t = time.perf_counter()
        state, _ = call(state)
        jax.block_until_ready(state)
        times.append(time.perf_counter() - t)
    return times[0], times[1:]


def peak_matmul_flops(n: int = 2048, repeats: int = 10) -> float:
    """FLOP/s of a jitted n x n float32 matmul (best of `repeats`)."""
    a = jax.random.normal(jax.random.PRNGKey(0), (n, n), jnp.float32)
    f = jax.jit(lambda x: x @ x)
    f(a).block_until_ready()
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        f(a).block_until_ready()
        best = min(best, time.perf_counter() - t)
    return 2 * n**3 / best


def _flops(compiled: Any) -> float:
    cost = compiled.cost_analysis()
    cost = cost[0] if isinstance(cost, list | tuple) else cost
    return float(cost["flops"])


def flops_per_env_step(trainer: Trainer, batch: int = 256) -> dict[str, float]:
    """Network FLOPs per joint env-step from XLA's cost analysis of one-step programs (no loops)."""
    net, cfg = trainer.network, trainer.config
    params = jax.eval_shape(lambda: trainer.init_one(jax.random.PRNGKey(0)).params)
    obs = jax.ShapeDtypeStruct(
        (1, batch, *trainer.task.obs_shape), jnp.uint8 if cfg.env.name == "overcooked" else jnp.float32
    )
    carry = jax.eval_shape(lambda: net.initial_carry((batch,)))
    first = jax.ShapeDtypeStruct((1, batch), jnp.bool_)
    fwd = jax.jit(net.apply).lower(params, carry, obs, first).compile()
    f32 = jax.ShapeDtypeStruct((1, batch), jnp.float32)
    i32 = jax.ShapeDtypeStruct((1, batch), jnp.int32)
    history = jax.ShapeDtypeStruct((1, batch, 0), jnp.int32)
    mb = Batch(obs, first, i32, f32, f32, f32, f32, history, i32, None, None, None, carry)
    grad = jax.jit(jax.grad(lambda p, b: ppo_loss(p, net, b, cfg.ppo)[0])).lower(params, mb).compile()
    forward, forward_backward = _flops(fwd) / batch, _flops(grad) / batch
    per_env_step = 2 * (forward + cfg.ppo.update_epochs * forward_backward)
    return {"forward": forward, "forward_backward": forward_backward, "per_env_step": per_env_step}


def measure_ours(preset: str, envs: int, steps: int, updates: int, repeats: int) -> dict[str, Any]:
    cfg = from_dict(
        TrainConfig,
        {
            "algorithm": "cec",
            "num_envs": envs,
            "num_steps": steps,
            "total_env_steps": 3_000_000_000,
            "updates_per_call": updates,
            "network": preset,
            "env": {"name": "overcooked", "levels": "generator", "overcooked": {"max_steps": 100}},
        },
    )
    trainer = Trainer(cfg)
    first_s, times = time_train_call(trainer, updates, repeats)
    median = statistics.median(times)
    flops = flops_per_env_step(trainer)
    sps = updates * cfg.steps_per_update / median
    return {
        "preset": preset,
        "num_envs": envs,
        "num_steps": steps,
        "updates_per_call": updates,
        "compile_s": round(first_s - median, 2),  # the first call's time beyond a timed one
        "times_s": [round(x, 3) for x in times],
        "env_steps_per_s": round(sps, 1),
        "flops_per_env_step": flops,
        "achieved_flops_per_s": sps * flops["per_env_step"],
    }


def measure_reference(python: str, repo: str, envs: int, steps: int, updates: int) -> dict[str, Any]:
    cmd = [
        python,
        str(PEER),
        "--repo",
        repo,
        "--num-envs",
        str(envs),
        "--num-steps",
        str(steps),
        "--updates",
        str(updates),
        "--mode",
        "cec",
    ]
    print(f"running the authors' script (long compile): {' '.join(cmd)}", file=sys.stderr, flush=True)
    out = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"the reference script failed ({out.returncode}):\n{out.stderr[-3000:]}")
    result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def _batch(text: str) -> tuple[int, int]:
    envs, _, steps = text.partition("x")
    return int(envs), int(steps)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--presets", nargs="+", default=["paper", "small", "reference"])
    ap.add_argument("--batches", nargs="+", default=["64x100", "256x100"], help="ENVSxSTEPS per rollout")
    ap.add_argument("--updates", type=int, default=2, help="updates per timed call")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--reference-repo", help="checkout of the authors' repository (enables the peer)")
    ap.add_argument("--reference-python", help="python of a venv with the authors' pinned stack")
    ap.add_argument("--reference-batch", default="64x100", help="ENVSxSTEPS for the peer comparison")
    ap.add_argument("--reference-updates", type=int, default=3)
    ap.add_argument("--out", type=Path, help="results JSON (default: benchmarks/results/...)")
    args = ap.parse_args(argv)

    peak = peak_matmul_flops()
    print(f"peak float32 matmul: {peak / 1e9:.1f} GFLOP/s", flush=True)
    rows = []
    for preset in args.presets:
        for text in args.batches:
            envs, steps = _batch(text)
            r = measure_ours(preset, envs, steps, args.updates, args.repeats)
            r["fraction_of_peak"] = r["achieved_flops_per_s"] / peak
            rows.append(r)
            print(
                f"{preset:9s} {envs:5d}x{steps:<4d} compile {r['compile_s']:6.1f} s | "
                f"{r['env_steps_per_s']:10.1f} env-steps/s | "
                f"{r['flops_per_env_step']['per_env_step'] / 1e6:7.1f} MFLOP/env-step | "
                f"{r['achieved_flops_per_s'] / 1e9:6.1f} GFLOP/s = "
                f"{100 * r['fraction_of_peak']:5.1f}% of peak",
                flush=True,
            )
    peer = None
    if args.reference_repo:
        if not args.reference_python:
            raise SystemExit("--reference-repo needs --reference-python (the venv with the authors' stack)")
        envs, steps = _batch(args.reference_batch)
        theirs = measure_reference(
            args.reference_python, args.reference_repo, envs, steps, args.reference_updates
        )
        ours = measure_ours("reference", envs, steps, args.reference_updates, args.repeats)
        peer = {"theirs": theirs, "ours": ours, "ratio": ours["env_steps_per_s"] / theirs["env_steps_per_s"]}
        print(
            f"authors' script, CEC, {envs}x{steps}: {theirs['env_steps_per_s']:.1f} env-steps/s "
            f"(compile {theirs['compile_s']:.0f} s) | ours, same network and batch: "
            f"{ours['env_steps_per_s']:.1f} "
            f"(compile {ours['compile_s']:.0f} s) | ratio {peer['ratio']:.2f}x",
            flush=True,
        )
    else:
        print("authors' script not measured (give --reference-repo and --reference-python)", flush=True)
    fields = {
        "peak_matmul_flops_per_s": peak,
        "rows": rows,
        "reference": peer,
    }
    save_result("train_throughput", fields, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
