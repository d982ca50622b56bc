"""Where a training update's time goes: the trainer's step for one preset and batch, split into its parts,
with XLA's cost analysis, the FLOP/s achieved against the device's peak and the environment's own speed on
the same kitchens and N, all measured in one run (JSON out).

Parts, each its own compiled call on one seed's state at the preset's batch (median of `--repeats` timed
calls after a compiling one):

* `env_only`: `num_steps` steps of the `num_envs` envs with uniform random actions, observations included
  (the same kitchens the rollout plays);
* `rollout`: the trainer's rollout (env, egocentric view and network per step, action sampling);
  `rollout_network` is the network alone on the same observations, step by step, and `rollout_env_and_rest`
  the difference;
* `gae`: rewards, GAE and seat flattening (`make_batch`);
* `update_forward`: the PPO loss over every epoch's minibatches, forward only; `update_backward`: the
  gradient computation beyond it; `optimizer`: gradient clipping and Adam, once per minibatch;
* `train_call`: the fused call `cec train` runs (rollout + update, `--updates` per call, every seed), per
  update; `host`: the per-call work of the training loop beyond it (fetching metrics to the host).

The JSON is written after each stage (the train call, the parts, the rest) with `"complete": false` until
the end, so a run stopped by a time limit (a lent GPU's window) still leaves what it measured.

Cost analysis: XLA's FLOPs and bytes accessed of the compiled train call, per env step. Peak: a large
jitted float32 matmul measured in the same run. With `--baseline-tree DIR` (a worktree of another commit)
the train call's env-steps/s of that tree's code is measured in a subprocess of the same run, on the same
config (or on `--baseline-config`, a path inside that tree, with `--baseline-set`: a recipe against the
recipe it replaces), and the ratio printed.

    python benchmarks/train_profile.py                         # the CPU recipe, on this machine
    git worktree add /tmp/base f4d07d1 && python benchmarks/train_profile.py --baseline-tree /tmp/base
    python benchmarks/train_profile.py --set num_envs=1024 ppo.num_minibatches=8   # another batch
    python benchmarks/train_profile.py --config configs/train/cec_overcooked_tts.yaml \
        --baseline-tree /tmp/base --baseline-config configs/train/cec_overcooked_cpu.yaml  # recipe vs recipe
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import optax

try:  # run as a script (benchmarks/ on sys.path) or as a module
    from train_throughput import peak_matmul_flops  # type: ignore[import-not-found]
except ImportError:
    from benchmarks.train_throughput import peak_matmul_flops

RESULTS = Path(__file__).parent / "results"
DEFAULT_CONFIG = Path(__file__).parent.parent / "configs" / "train" / "cec_overcooked_cpu.yaml"


def timed(fn: Callable[..., Any], *args: Any, repeats: int) -> float:
    """Median seconds of `repeats` calls of a compiled function, after one call that compiles it."""
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def cost(compiled: Any) -> dict[str, float]:
    """XLA's cost analysis of a compiled call: flops and bytes accessed."""
    c = compiled.cost_analysis()
    c = c[0] if isinstance(c, list | tuple) else c
    return {"flops": float(c.get("flops", 0.0)), "bytes": float(c.get("bytes accessed", 0.0))}


def load_trainer(config: Path, overrides: list[str]) -> Any:
    from cec.config import load_config
    from cec.training.config import TrainConfig
    from cec.training.trainer import Trainer

    return Trainer(load_config(TrainConfig, config, overrides))


def train_call_speed(trainer: Any, updates: int, repeats: int) -> dict[str, Any]:
    """env-steps/s of the trainer's fused call (every seed), its compile time and the host's per-call work
    (fetching the metrics, as the training loop does)."""
    cfg = trainer.config
    state = trainer.init()
    call = trainer.train_call(updates)
    steps = updates * cfg.steps_per_update * cfg.num_seeds
    t = time.perf_counter()
    state, metrics = call(state)
    jax.block_until_ready(state)
    first = time.perf_counter() - t
    device, host, cpu = [], [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        state, metrics = call(state)
        jax.block_until_ready(state)
        mid = time.perf_counter()
        jax.device_get(metrics)
        device.append(mid - t)
        host.append(time.perf_counter() - mid)
        cpu.append(time.process_time() - c)
    median = statistics.median(device)
    out: dict[str, Any] = {
        "updates_per_call": updates,
        "compile_s": round(first - median, 2),
        "s_per_update": median / updates,
        "host_s_per_update": statistics.median(host) / updates,
        "env_steps_per_s": steps / median,
        # the process's CPU time (every thread) per env step: the cost in core-seconds, which a machine
        # shared with other work inflates far less than the wall time above
        "cpu_s_per_env_step": statistics.median(cpu) / steps,
    }
    return out


def flops_and_bytes(trainer: Any) -> dict[str, float]:
    """XLA's cost analysis per env step, from loop-free programs (XLA counts a loop's body once, so the
    fused call's own analysis undercounts): the network's step on every env and seat (x `num_steps`), the
    PPO loss's value and gradient on one minibatch and one optimizer step (x epochs x minibatches). The
    environment's integer work is left out (the `env_only` part shows its time)."""
    from cec.training.ppo import Batch, ppo_loss
    from cec.training.rollout import NUM_SEATS, policy_step

    cfg, net = trainer.config, trainer.network
    state = jax.eval_shape(lambda: jax.tree.map(lambda x: x[0], trainer.init()))
    c = state.carry
    step = jax.jit(lambda p, lstm, o, f, h: policy_step(net, p, lstm, o, f, h))
    rollout = cost(step.lower(state.params, c.lstm, c.obs, c.first, c.history).compile())
    n = cfg.num_envs * NUM_SEATS // cfg.ppo.num_minibatches
    seq = lambda dtype, *shape: jax.ShapeDtypeStruct((cfg.num_steps, n, *shape), dtype)  # noqa: E731
    f32, i32 = seq(jnp.float32), seq(jnp.int32)
    lstm = jax.tree.map(lambda x: jax.ShapeDtypeStruct((n, x.shape[-1]), x.dtype), c.lstm)
    mb = Batch(
        seq(c.obs.dtype, *c.obs.shape[2:]),
        seq(jnp.bool_),
        i32,
        f32,
        f32,
        f32,
        f32,
        seq(jnp.int32, c.history.shape[-1]),
        i32,
        None,
        None,
        None,
        lstm,
    )
    grad = jax.jit(jax.value_and_grad(lambda p, b: ppo_loss(p, net, b, cfg.ppo)[0]))
    update = cost(grad.lower(state.params, mb).compile())
    adam = jax.jit(lambda g, o, p: trainer.optimizer.update(g, o, p))
    opt = cost(adam.lower(state.params, state.opt_state, state.params).compile())
    per_update = cfg.ppo.update_epochs * cfg.ppo.num_minibatches
    return {
        k: (cfg.num_steps * rollout[k] + per_update * (update[k] + opt[k])) / cfg.steps_per_update
        for k in ("flops", "bytes")
    }


def profile_parts(trainer: Any, repeats: int) -> dict[str, float]:
    """Seconds per update of each part (one seed's state; see the module docstring)."""
    from cec.training.ppo import Batch, make_batch, ppo_loss
    from cec.training.rollout import NUM_SEATS, policy_step

    cfg, task, net = trainer.config, trainer.task, trainer.network
    state = jax.tree.map(lambda x: x[0], trainer.init())
    key = jax.random.PRNGKey(1)
    k_levels, k_roll, k_update = jax.random.split(key, 3)
    collect = jax.jit(lambda p, c: trainer.collect(p, c, k_levels, k_roll))
    carry, traj = collect(state.params, state.carry)
    parts: dict[str, float] = {}

    levels = task.sample_levels(k_levels, carry.env_id, cfg.levels_per_env)

    def env_only(c: Any) -> jax.Array:
        def body(s: Any, k: jax.Array) -> tuple[Any, jax.Array]:
            e = c.obs.shape[0]
            actions = jax.random.randint(k, (e, NUM_SEATS), 0, task.num_actions)
            out = jax.vmap(task.step, in_axes=(0, 0, 0, 0, None))(
                jax.random.split(k, e), s, actions, levels, trainer.env_params
            )
            return out.state, out.obs.sum(dtype=jnp.float32) + out.reward.sum()

        return jax.lax.scan(body, c.env_state, jax.random.split(k_roll, cfg.num_steps))[1].sum()

    parts["env_only"] = timed(jax.jit(env_only), carry, repeats=repeats)
    parts["rollout"] = timed(collect, state.params, state.carry, repeats=repeats)

    def network_only(p: Any, obs: jax.Array, first: jax.Array) -> jax.Array:
        def body(lstm: Any, x: tuple[jax.Array, jax.Array]) -> tuple[Any, jax.Array]:
            lstm, logits, value = policy_step(net, p, lstm, x[0], x[1], traj.history[0])
            return lstm, logits.sum() + value.sum()

        return jax.lax.scan(body, traj.init_lstm, (obs, first))[1].sum()

    parts["rollout_network"] = timed(
        jax.jit(network_only), state.params, traj.obs, traj.first, repeats=repeats
    )
    parts["rollout_env_and_rest"] = max(parts["rollout"] - parts["rollout_network"], 0.0)

    gae = jax.jit(lambda t: make_batch(t, jnp.float32(1.0), cfg.ppo.gamma, cfg.ppo.gae_lambda))
    parts["gae"] = timed(gae, traj, repeats=repeats)
    batch = gae(traj)

    n, m, epochs = batch.action.shape[1], cfg.ppo.num_minibatches, cfg.ppo.update_epochs
    orders = jnp.stack(
        [jax.random.permutation(k, n).reshape((m, n // m)) for k in jax.random.split(k_update, epochs)]
    )
    orders = orders.reshape((epochs * m, n // m))

    def minibatch(idx: jax.Array) -> Batch:
        time_major = jax.tree.map(lambda x: jnp.take(x, idx, axis=1), batch[:-1])
        return Batch._make([*time_major, jax.tree.map(lambda x: x[idx], batch.init_lstm)])

    def over_minibatches(fn: Callable[[Any, Batch], jax.Array]) -> Callable[[Any], jax.Array]:
        def run(p: Any) -> jax.Array:
            return jax.lax.scan(lambda acc, idx: (acc + fn(p, minibatch(idx)), None), jnp.float32(0), orders)[
                0
            ]

        return jax.jit(run)

    loss = lambda p, mb: ppo_loss(p, net, mb, cfg.ppo)[0]  # noqa: E731
    grad_norm = lambda p, mb: optax.tree.norm(jax.grad(loss)(p, mb))  # noqa: E731
    parts["update_forward"] = timed(over_minibatches(loss), state.params, repeats=repeats)
    fwd_bwd = timed(over_minibatches(grad_norm), state.params, repeats=repeats)
    parts["update_backward"] = max(fwd_bwd - parts["update_forward"], 0.0)

    grads = jax.tree.map(jnp.ones_like, state.params)

    def adam(p: Any, o: Any) -> Any:
        def step(c: Any, _: Any) -> tuple[Any, None]:
            updates, o2 = trainer.optimizer.update(grads, c[1], c[0])
            return (jax.tree.map(jnp.add, c[0], updates), o2), None

        return jax.lax.scan(step, (p, o), None, length=epochs * m)[0]

    parts["optimizer"] = timed(jax.jit(adam), state.params, state.opt_state, repeats=repeats)
    learn = jax.jit(lambda p, o, t: trainer.learn(p, o, state.update, t, k_update))
    parts["update"] = timed(learn, state.params, state.opt_state, traj, repeats=repeats)
    return parts


def baseline(tree: Path, config: Path, overrides: list[str], updates: int, repeats: int) -> dict[str, Any]:
    """The train call's speed with another tree's code (a subprocess importing `cec` from `tree`)."""
    cmd = [
        sys.executable,
        __file__,
        "--throughput-only",
        "--config",
        str(config),
        "--updates",
        str(updates),
        "--repeats",
        str(repeats),
        "--set",
        *overrides,
    ]
    env = {**os.environ, "PYTHONPATH": f"{tree}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    print(f"baseline: {tree}", file=sys.stderr, flush=True)
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tree, check=False)
    if out.returncode != 0:
        raise SystemExit(f"the baseline tree's measurement failed ({out.returncode}):\n{out.stderr[-3000:]}")
    result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    result["tree"] = str(tree)
    result["git"] = subprocess.run(
        ["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
    ).stdout.strip()
    return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--config", type=Path, default=DEFAULT_CONFIG, help="training config (default: the CPU recipe)"
    )
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="config overrides")
    ap.add_argument("--updates", type=int, default=2, help="updates per timed train call")
    ap.add_argument("--repeats", type=int, default=3, help="timed calls per part (median)")
    ap.add_argument(
        "--baseline-tree", type=Path, help="a worktree of another commit, measured in the same run"
    )
    ap.add_argument(
        "--baseline-config", type=Path, help="the baseline's config, in the baseline tree (default: --config)"
    )
    ap.add_argument(
        "--baseline-set", nargs="*", metavar="KEY=VALUE", help="the baseline's overrides (default: --set)"
    )
    ap.add_argument("--throughput-only", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument(
        "--out", type=Path, help="results JSON (default: benchmarks/results/train_profile_<device>.json)"
    )
    args = ap.parse_args(argv)
    config = args.config.resolve()
    overrides = [*args.set, "num_seeds=1", f"updates_per_call={args.updates}"]

    trainer = load_trainer(config, overrides)
    if args.throughput_only:  # the baseline's subprocess: one JSON line
        print(json.dumps(train_call_speed(trainer, args.updates, args.repeats)))
        return 0

    from apps.machine import machine_info
    from cec.checkpoints import code_version

    cfg = trainer.config
    peak = peak_matmul_flops(2048 if jax.devices()[0].platform == "cpu" else 8192)
    print(
        f"{cfg.num_envs} envs x {cfg.num_steps} steps, {cfg.ppo.update_epochs} epochs x "
        f"{cfg.ppo.num_minibatches} minibatches; peak float32 matmul {peak / 1e9:.1f} GFLOP/s",
        flush=True,
    )
    device = jax.devices()[0].platform
    out = args.out or RESULTS / f"train_profile_{device}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {
        "benchmark": "train_profile",
        "complete": False,  # written after each stage: a run cut short still leaves what it measured
        "date": datetime.date.today().isoformat(),
        "git": code_version(short=True),
        "machine": machine_info(),
        "config": str(config.relative_to(Path.cwd()) if config.is_relative_to(Path.cwd()) else config),
        "overrides": args.set,
        "num_envs": cfg.num_envs,
        "num_steps": cfg.num_steps,
        "update_epochs": cfg.ppo.update_epochs,
        "num_minibatches": cfg.ppo.num_minibatches,
        "peak_matmul_flops_per_s": peak,
        # JAX_DEFAULT_MATMUL_PRECISION (e.g. bfloat16: one bf16 pass, float32 accumulation) applies to the
        # peak's matmul and to the trainer's alike
        "matmul_precision": str(jax.config.jax_default_matmul_precision or "default"),
    }
    call = result["train_call"] = train_call_speed(trainer, args.updates, args.repeats)
    print(
        f"train call: {call['env_steps_per_s']:,.0f} env-steps/s ({call['compile_s']:.1f} s to compile)",
        flush=True,
    )
    out.write_text(json.dumps(result, indent=2) + "\n")
    parts = result["parts_s_per_update"] = profile_parts(trainer, args.repeats)
    out.write_text(json.dumps(result, indent=2) + "\n")
    xla = flops_and_bytes(trainer)
    call["flops_per_env_step"], call["bytes_per_env_step"] = xla["flops"], xla["bytes"]
    env_sps = cfg.steps_per_update / parts["env_only"]
    achieved = call["env_steps_per_s"] * call["flops_per_env_step"]
    for name, s in parts.items():
        print(
            f"  {name:22s} {1000 * s:9.1f} ms/update  "
            f"({100 * s / call['s_per_update']:5.1f}% of the train call)"
        )
    print(
        f"  {'train_call':22s} {1000 * call['s_per_update']:9.1f} ms/update  "
        f"(host {1000 * call['host_s_per_update']:.1f})"
    )
    print(
        f"training {call['env_steps_per_s']:,.0f} env-steps/s | env alone {env_sps:,.0f} | ratio "
        f"{call['env_steps_per_s'] / env_sps:.4f} | {call['flops_per_env_step'] / 1e6:.2f} "
        f"MFLOP and {call['bytes_per_env_step'] / 1e6:.2f} MB per env step | "
        f"{achieved / 1e9:.1f} GFLOP/s = {100 * achieved / peak:.1f}% of peak",
        flush=True,
    )
    result |= {
        "complete": True,
        "env_only_steps_per_s": env_sps,
        "train_to_env_only": call["env_steps_per_s"] / env_sps,
        "achieved_flops_per_s": achieved,
        "fraction_of_peak": achieved / peak,
    }
    if args.baseline_tree:
        tree = args.baseline_tree.resolve()
        base_config = tree / args.baseline_config if args.baseline_config else config
        if not base_config.is_file():
            raise SystemExit(f"--baseline-config: no {base_config} in the baseline tree")
        base_set = args.set if args.baseline_set is None else args.baseline_set
        base = baseline(tree, base_config, base_set, args.updates, args.repeats)
        base |= {"config": str(base_config), "overrides": base_set}
        result["baseline"] = base
        result["speedup_vs_baseline"] = call["env_steps_per_s"] / base["env_steps_per_s"]
        print(
            f"baseline {base['git']}: {base['env_steps_per_s']:,.0f} env-steps/s | this tree "
            f"{call['env_steps_per_s']:,.0f} | ratio {result['speedup_vs_baseline']:.2f}x",
            flush=True,
        )
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
