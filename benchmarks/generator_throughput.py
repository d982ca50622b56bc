"""Levels per second of the procedural generator, what its solvability check and held-out exclusion cost,
and what generating a fresh level for every episode adds to a CEC-mode env step.

    python benchmarks/generator_throughput.py              # about a minute on 2 CPU cores
    python benchmarks/generator_throughput.py --repeats 3 --batches 1 1024
    python benchmarks/generator_throughput.py --reference-repo ~/crossEnvCooperation \\
        --reference-python ~/venvs/cec-ref/bin/python     # + the paper authors' generator (slow compile)

Sections (all timed the way `env_throughput.py` times: compiled first, compile time reported separately,
then the functions of one section in interleaved rounds A B C A B C ... so drifting machine load hits all
alike, median per function):

1. `jit(generate_batch)` (vmapped `generate`, default `GeneratorConfig`) at several batch sizes.
2. The cost breakdown at one batch size: `_sample` alone (vmapped; no check, no exclusion), + the
   solvability check, + the held-out exclusion (fingerprint compared with the 105 held-out ones), and the
   full `generate_batch` (which also carries the resampling `while_loop`; by construction it never runs).
3. A CEC-mode env step: N envs, random actions, `step_autoreset` with `EnvParams(max_steps=100)` (the
   paper's CEC episodes), observations consumed by an int32 sum as in `env_throughput.py`. Episodes are
   synchronised as in the paper's training (every env starts together; a rollout of 100 steps is one
   episode). "cec" draws N new levels (one per env) at the start of every episode, inside the measured
   region, and writes them into each env's buffer: the level the env auto-resets onto when the episode
   ends. "fixed" is the same nested scan with the buffer never refreshed. The measured region is a whole
   number of episodes (default 2 x 100 steps) rather than env_throughput's 128 steps, so that the generator
   runs exactly once per env per episode, as it would in training.
4. Optional peer: the paper authors' generator (`Overcooked.reset` with `random_reset=True`,
   `random_reset_fn='reset_all'`, vmapped) run by its own Python (their pinned jax 0.4.18) in a subprocess.
   It is not interleaved with ours (its compile alone takes minutes); ours is timed again at the same
   batch right after it, and the ratio uses those figures.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from cec.envs import overcooked as oc
from cec.levels import Level
from cec.levels.fingerprint import fingerprint
from cec.levels.generator import GeneratorConfig, _sample, generate_batch
from cec.levels.heldout import heldout_fingerprints
from cec.levels.solvability import check

try:  # run as a script (benchmarks/ on sys.path) or as `python -m benchmarks.generator_throughput`
    from env_throughput import CONSUMERS, git_rev, machine  # type: ignore[import-not-found]
except ImportError:  # pragma: no cover
    from benchmarks.env_throughput import CONSUMERS, git_rev, machine

RESULTS = Path(__file__).parent / "results"

#: shared/BENCHMARKS.md, measured on this project's 2-core CPU machine kind (not in this run).
REFERENCE_CITED = {"batch": 1024, "levels_per_s": 6100, "compile_s": 676, "source": "shared/BENCHMARKS.md"}

Fn = Callable[..., Any]


# ---------------------------------------------------------------------------------------------------
# TIMING
# ---------------------------------------------------------------------------------------------------


def measure(
    fns: dict[str, tuple[Fn, tuple[Any, ...]]], repeats: int, min_sample_s: float
) -> dict[str, dict[str, Any]]:
    """Compiles each `fn(key, *args)`, then times them in interleaved rounds.

    A timed sample is the mean of `calls` calls (each with its own key, each waited for, so that calls do
    not overlap), enough to last `min_sample_s`, so that tiny batches are not measured at the resolution
    of the clock. Returns, per function, the compile time, the median seconds per call and every sample
    (sample i of every function comes from the same round).
    """
    compiled: dict[str, Any] = {}
    compile_s: dict[str, float] = {}
    calls: dict[str, int] = {}
    for name, (fn, args) in fns.items():
        key = jax.random.PRNGKey(0)
        t0 = time.perf_counter()
        compiled[name] = jax.jit(fn).lower(key, *args).compile()
        compile_s[name] = time.perf_counter() - t0
        jax.block_until_ready(compiled[name](key, *args))  # warm-up
        t0 = time.perf_counter()
        jax.block_until_ready(compiled[name](jax.random.PRNGKey(1), *args))
        calls[name] = max(1, math.ceil(min_sample_s / max(time.perf_counter() - t0, 1e-7)))
    times: dict[str, list[float]] = {name: [] for name in fns}
    for r in range(repeats):
        for name, c in compiled.items():
            args = fns[name][1]
            keys = [jax.random.PRNGKey(1000 * (r + 1) + i) for i in range(calls[name])]
            jax.block_until_ready(keys)
            t0 = time.perf_counter()
            for k in keys:
                jax.block_until_ready(c(k, *args))
            times[name].append((time.perf_counter() - t0) / calls[name])
    return {
        name: {
            "compile_s": compile_s[name],
            "median_s": statistics.median(times[name]),
            "calls_per_sample": calls[name],
            "samples_s": times[name],
        }
        for name in fns
    }


# ---------------------------------------------------------------------------------------------------
# 1-2. GENERATION AND ITS STAGES
# ---------------------------------------------------------------------------------------------------


def generate_fn(n: int, config: GeneratorConfig) -> Fn:
    return lambda key: generate_batch(key, n, config)


def stage_fn(n: int, config: GeneratorConfig, stage: str) -> Fn:
    """One draw per level, without the resampling loop: `sample`, `+check` (the verdict is returned, so
    it is computed) or `+exclusion` (the generator's full rejection predicate)."""
    held_out = jnp.asarray(heldout_fingerprints())

    def one(key: jax.Array) -> tuple[Level, jax.Array] | Level:
        level = _sample(key, config)[0]
        if stage == "sample":
            return level
        rejected = ~check(level, config.allow_decoys).solvable
        if stage == "+exclusion":
            rejected = rejected | jnp.any(jnp.all(fingerprint(level)[None, :] == held_out, axis=-1))
        return level, rejected

    return lambda key: jax.vmap(one)(jax.random.split(key, n))


# ---------------------------------------------------------------------------------------------------
# 3. CEC-MODE ENV STEP
# ---------------------------------------------------------------------------------------------------


def cec_fn(n_envs: int, episodes: int, params: oc.EnvParams, config: GeneratorConfig, refresh: bool) -> Fn:
    """`episodes` x (refresh every env's level buffer with a newly generated level, if `refresh`; then a
    scan of `params.max_steps` vmapped `step_autoreset` steps). The first episode's levels are an input
    (generated outside the measured region, the same for both variants)."""
    steps = int(params.max_steps)
    consume = CONSUMERS["sum_i32"]

    def run(key: jax.Array, first: Level) -> jax.Array:
        k_reset, k_run = jax.random.split(key)
        _, state = jax.vmap(oc.reset, in_axes=(0, 0, None))(jax.random.split(k_reset, n_envs), first, params)
        buffer = jax.tree.map(lambda x: x[:, None], first)  # (N, K=1, ...): the level after this episode

        def step(state: oc.EnvState, k: jax.Array, buffer: Level) -> tuple[oc.EnvState, jax.Array]:
            k_act, k_step = jax.random.split(k)
            actions = jax.random.randint(k_act, (n_envs, 2), 0, oc.NUM_ACTIONS)
            out = jax.vmap(oc.step_autoreset, in_axes=(0, 0, 0, 0, None))(
                jax.random.split(k_step, n_envs), state, actions, buffer, params
            )
            return out.state, consume(out.obs) + out.reward.sum()

        def episode(
            carry: tuple[oc.EnvState, Level], k: jax.Array
        ) -> tuple[tuple[oc.EnvState, Level], jax.Array]:
            state, buffer = carry
            k_gen, k_steps = jax.random.split(k)
            if refresh:  # one new level per env per episode: played after this episode's auto-reset
                buffer = jax.tree.map(lambda x: x[:, None], generate_batch(k_gen, n_envs, config))
            state, consumed = jax.lax.scan(
                lambda s, kk: step(s, kk, buffer), state, jax.random.split(k_steps, steps)
            )
            return (state, buffer), consumed

        _, consumed = jax.lax.scan(episode, (state, buffer), jax.random.split(k_run, episodes))
        return consumed

    return run


# ---------------------------------------------------------------------------------------------------
# 4. PEER: THE PAPER AUTHORS' GENERATOR (CEC-MODE RESET), IN ITS OWN INTERPRETER
# ---------------------------------------------------------------------------------------------------

# Written to a temp file and run with the reference virtualenv's Python, PYTHONPATH = the reference repo.
# Prints one line "RESULT {json}" at the end.
REFERENCE_SCRIPT = r"""
import json, statistics, sys, time
import jax
import jax.numpy as jnp
from jaxmarl.environments.overcooked import Overcooked, overcooked_layouts

batch, repeats = int(sys.argv[1]), int(sys.argv[2])
layout = overcooked_layouts["cramped_room_9"]  # ignored in CEC mode (random_reset=True)
env = Overcooked(layout=layout, random_reset=True, max_steps=100, check_held_out=False)
# Overcooked.reset always traces its held-out comparison, which fails unless these arrays are set (the
# training scripts assign 105 real ones). 105 dummy entries that never match: no position is 99.
_, s = env.custom_reset(jax.random.PRNGKey(0), layout=layout, random_reset=False, shuffle_inv_and_pot=False)
env.held_out_goal = jnp.full((105,) + s.goal_pos.shape, 99, s.goal_pos.dtype)
env.held_out_pot = jnp.full((105,) + s.pot_pos.shape, 99, s.pot_pos.dtype)
env.held_out_wall = jnp.zeros((105,) + s.wall_map.shape, s.wall_map.dtype)


def run(key):
    # CEC mode: params={'random_reset_fn': 'reset_all'} is reset's default. The state (layout, positions,
    # maze map) is returned; the observation is not, so XLA may drop it (ours returns only the level too).
    reset = lambda k: env.reset(k, {"random_reset_fn": "reset_all"})
    _, state = jax.vmap(reset)(jax.random.split(key, batch))
    return state


key = jax.random.PRNGKey(0)
t0 = time.perf_counter()
compiled = jax.jit(run).lower(key).compile()
compile_s = time.perf_counter() - t0
jax.block_until_ready(compiled(key))
times = []
for r in range(repeats):
    t0 = time.perf_counter()
    jax.block_until_ready(compiled(jax.random.PRNGKey(r + 1)))
    times.append(time.perf_counter() - t0)
med = statistics.median(times)
print("RESULT " + json.dumps({
    "batch": batch, "compile_s": compile_s, "median_s": med, "levels_per_s": batch / med,
    "samples_s": times, "jax": jax.__version__, "device": str(jax.devices()[0]),
}), flush=True)
"""


def reference_path_error(repo: Path, python: Path) -> str | None:
    """Why the peer cannot run with these paths, or None."""
    repo, python = repo.expanduser().resolve(), python.expanduser()
    env_file = Path("jaxmarl", "environments", "overcooked", "overcooked.py")
    if not (repo / env_file).is_file():
        return f"--reference-repo {repo}: no {env_file} there; give a checkout of KJha02/crossEnvCooperation"
    if not (python.is_file() and os.access(python, os.X_OK)):
        return f"--reference-python {python}: not an executable file"
    return None


def run_reference(repo: Path, python: Path, batch: int, repeats: int, timeout_s: float) -> dict[str, Any]:
    """Runs REFERENCE_SCRIPT; returns its result, or {"error": ...} with a readable reason."""
    error = reference_path_error(repo, python)
    if error:
        return {"error": error}
    repo, python = repo.expanduser().resolve(), python.expanduser()
    with tempfile.NamedTemporaryFile("w", suffix="_cec_reference_reset.py", delete=False) as f:
        f.write(REFERENCE_SCRIPT)
        script = f.name
    env = {**os.environ, "PYTHONPATH": str(repo)}
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(
            [str(python), script, str(batch), str(repeats)],
            env=env,
            cwd=str(repo),
            capture_output=True,
            text=True,
            timeout=timeout_s,
        )
    except subprocess.TimeoutExpired:
        return {
            "error": f"the reference run did not finish within --reference-timeout {timeout_s:.0f} s "
            "(its XLA compile alone took 4-11 minutes on 2 CPU cores)"
        }
    finally:
        Path(script).unlink(missing_ok=True)
    wall = time.perf_counter() - t0
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        tail = "\n".join((proc.stdout + proc.stderr).strip().splitlines()[-15:])
        return {"error": f"the reference run failed (exit {proc.returncode}):\n{tail}"}
    out: dict[str, Any] = json.loads(lines[-1][len("RESULT ") :])
    out["wall_s"] = wall
    out["repo"] = str(repo)
    rev = subprocess.run(
        ["git", "-C", str(repo), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    )
    out["repo_git"] = rev.stdout.strip() or "unknown (not a git checkout)"
    return out


# ---------------------------------------------------------------------------------------------------
# MAIN
# ---------------------------------------------------------------------------------------------------


def rate(n: int, seconds: float) -> dict[str, float]:
    return {"levels_per_s": n / seconds, "us_per_level": 1e6 * seconds / n}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 1024, 16384], help="generation batch sizes")
    ap.add_argument("--breakdown-batch", type=int, default=16384, help="batch size of the cost breakdown")
    ap.add_argument("--n-envs", type=int, default=1024, help="envs in the CEC-mode step")
    ap.add_argument("--episodes", type=int, default=2, help="episodes per measured CEC-mode run")
    ap.add_argument("--max-steps", type=int, default=100, help="episode length (the paper's CEC: 100)")
    ap.add_argument("--repeats", type=int, default=9, help="timed samples per function (median reported)")
    ap.add_argument("--breakdown-repeats", type=int, default=25, help="timed rounds of the breakdown")
    ap.add_argument("--cec-repeats", type=int, default=25, help="timed rounds of the CEC-mode step")
    ap.add_argument("--min-sample-s", type=float, default=0.05, help="shortest timed sample (batch 1)")
    ap.add_argument("--reference-repo", type=Path, help="checkout of KJha02/crossEnvCooperation")
    ap.add_argument("--reference-python", type=Path, help="python of a venv with that repo's jax 0.4.18")
    ap.add_argument("--reference-batch", type=int, default=1024, help="batch of the peer's vmapped reset")
    ap.add_argument("--reference-repeats", type=int, default=5, help="timed runs of the peer")
    ap.add_argument("--reference-timeout", type=float, default=1800.0, help="seconds (compile is slow)")
    ap.add_argument("--out", type=Path, default=None, help="results JSON (default: benchmarks/results/)")
    args = ap.parse_args(argv)
    if (args.reference_repo is None) != (args.reference_python is None):
        ap.error("--reference-repo and --reference-python go together")
    if args.reference_repo is not None:
        error = reference_path_error(args.reference_repo, args.reference_python)
        if error:
            ap.error(error)

    config = GeneratorConfig()
    result: dict[str, Any] = {
        "benchmark": "generator_throughput",
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "git": git_rev(),
        "machine": machine(),
        "argv": sys.argv[1:] if argv is None else list(argv),
        "config": "GeneratorConfig() (default)",
        "repeats": {
            "generation": args.repeats,
            "breakdown": args.breakdown_repeats,
            "cec_step": args.cec_repeats,
        },
    }

    # 1. Levels/s per batch size.
    print("1. jit(generate_batch), default GeneratorConfig", flush=True)
    print(f"{'batch':>7s} {'levels/s':>12s} {'us/level':>10s} {'compile s':>10s}", flush=True)
    gen = measure(
        {f"batch {n}": (generate_fn(n, config), ()) for n in args.batches}, args.repeats, args.min_sample_s
    )
    rows = []
    for n in args.batches:
        m = gen[f"batch {n}"]
        r = rate(n, m["median_s"])
        rows.append({"batch": n, **r, **m})
        print(
            f"{n:7d} {r['levels_per_s']:12,.0f} {r['us_per_level']:10.2f} {m['compile_s']:10.1f}", flush=True
        )
    result["generation"] = rows

    # 2. Breakdown.
    nb = args.breakdown_batch
    print(
        f"\n2. cost breakdown at batch {nb} (one draw per level, no resampling loop unless stated)",
        flush=True,
    )
    stages = {
        "sample": ("_sample only", stage_fn(nb, config, "sample")),
        "+check": ("+ solvability check", stage_fn(nb, config, "+check")),
        "+exclusion": ("+ held-out exclusion (105 fingerprints)", stage_fn(nb, config, "+exclusion")),
        "generate": ("= generate_batch (+ resampling loop)", generate_fn(nb, config)),
    }
    bd = measure({k: (fn, ()) for k, (_, fn) in stages.items()}, args.breakdown_repeats, args.min_sample_s)
    print(
        f"{'stage':42s} {'levels/s':>12s} {'us/level':>10s} {'added us':>9s} {'compile s':>10s}", flush=True
    )
    # What a stage adds: the median over rounds of (this stage - the previous one), timed back to back.
    breakdown, prev = [], None
    for k, (label, _) in stages.items():
        r = rate(nb, bd[k]["median_s"])
        added = None
        if prev is not None:
            diffs = zip(bd[k]["samples_s"], bd[prev]["samples_s"], strict=True)
            added = statistics.median(1e6 * (t - u) / nb for t, u in diffs)
        prev = k
        breakdown.append({"stage": k, "label": label, "batch": nb, **r, "added_us_per_level": added, **bd[k]})
        add = "-" if added is None else f"{added:+.2f}"
        print(
            f"{label:42s} {r['levels_per_s']:12,.0f} {r['us_per_level']:10.2f} {add:>9s} "
            f"{bd[k]['compile_s']:10.1f}",
            flush=True,
        )
    result["breakdown"] = breakdown
    result["breakdown_added_method"] = "median over interleaved rounds of the per-level time difference"

    # 3. CEC-mode env step.
    n, eps, params = args.n_envs, args.episodes, oc.EnvParams(max_steps=args.max_steps)
    steps = eps * args.max_steps
    print(
        f"\n3. CEC-mode env step: N={n}, {eps} episodes x {args.max_steps} steps of step_autoreset, random "
        "actions, obs consumed (int32 sum)",
        flush=True,
    )
    first = generate_batch(jax.random.PRNGKey(12345), n, config)
    cec = measure(
        {
            "fixed": (cec_fn(n, eps, params, config, refresh=False), (first,)),
            "cec": (cec_fn(n, eps, params, config, refresh=True), (first,)),
            "generate": (generate_fn(n, config), ()),
        },
        args.cec_repeats,
        0.0,
    )
    fixed_s, cec_s = cec["fixed"]["median_s"], cec["cec"]["median_s"]
    # Overhead: the median over rounds of cec / fixed timed back to back (robust to drifting load), and
    # the same predicted from generation alone at batch N timed in the same rounds.
    pairs = zip(cec["cec"]["samples_s"], cec["fixed"]["samples_s"], cec["generate"]["samples_s"], strict=True)
    ratios = [(c_s / f_s, eps * g_s / f_s) for c_s, f_s, g_s in pairs]
    overhead = 100.0 * (statistics.median(r for r, _ in ratios) - 1.0)
    predicted = 100.0 * statistics.median(p for _, p in ratios)
    per_step_us = 1e6 * fixed_s * overhead / 100.0 / (n * steps)
    print(f"{'buffer':44s} {'env-steps/s':>12s} {'us/env-step':>12s} {'compile s':>10s}", flush=True)
    for k, label in (("fixed", "fixed (no generation)"), ("cec", f"{n} new levels per episode (CEC)")):
        s = cec[k]["median_s"]
        print(
            f"{label:44s} {n * steps / s:12,.0f} {1e6 * s / (n * steps):12.3f} {cec[k]['compile_s']:10.1f}",
            flush=True,
        )
    print(
        f"generation per episode adds {overhead:+.1f}% to the env-only step "
        f"({per_step_us:+.3f} us per env-step)"
        + f"; predicted from generating {n} levels alone, per {args.max_steps} steps: {predicted:+.1f}%",
        flush=True,
    )
    print(
        "  (upper bound for training: a training step also runs the network forward and the PPO update, "
        "which this env-only figure leaves out, so the generator's share of a training step is smaller; "
        "acceptance target < 5% of a training step)",
        flush=True,
    )
    result["cec_step"] = {
        "n_envs": n,
        "episodes": eps,
        "max_steps": args.max_steps,
        "steps": steps,
        "consumer": "sum_i32",
        "method": "episodes x (refresh every env's buffer with generate_batch(N) [cec only]; scan of "
        "max_steps vmapped step_autoreset); synchronised episodes",
        "fixed": {**cec["fixed"], "env_steps_per_s": n * steps / fixed_s},
        "cec": {**cec["cec"], "env_steps_per_s": n * steps / cec_s},
        "generate_n": {**cec["generate"], **rate(n, cec["generate"]["median_s"])},
        "overhead_pct": overhead,
        "overhead_method": "median over interleaved rounds of (cec time / fixed time) - 1",
        "added_us_per_env_step": per_step_us,
        "predicted_overhead_pct": predicted,
        "predicted_method": "median over rounds of episodes x (generate_batch(N) time) / fixed time",
        "note": "env-only: an upper bound of the share of a training step (which also includes the network)",
    }

    # 4. Peer.
    rc = 0
    print(
        "\n4. peer: the paper authors' generator (vmapped Overcooked.reset, CEC mode, no solvability check)"
    )
    if args.reference_repo is None:
        c = REFERENCE_CITED
        print(
            "skipped (give --reference-repo and --reference-python to measure it). Not measured in this run: "
            f"shared/BENCHMARKS.md reports ~{c['levels_per_s']:,} levels/s at batch {c['batch']} after "
            f"{c['compile_s']} s of compilation on this 2-core machine kind",
            flush=True,
        )
        ours_1024 = gen.get(f"batch {c['batch']}")
        if ours_1024 is not None:
            print(
                f"  (ours at batch {c['batch']} in this run: {c['batch'] / ours_1024['median_s']:,.0f} "
                "levels/s; a ratio across runs is indicative only)"
            )
        result["reference"] = {"measured": False, "cited": c}
    else:
        b = args.reference_batch
        print(
            f"running it with {args.reference_python} (batch {b}, timeout {args.reference_timeout:.0f} s); "
            "its compile takes minutes...",
            flush=True,
        )
        peer = run_reference(
            args.reference_repo, args.reference_python, b, args.reference_repeats, args.reference_timeout
        )
        if "error" in peer:
            print(f"peer failed: {peer['error']}", file=sys.stderr, flush=True)
            result["reference"] = {"measured": False, **peer}
            rc = 1
        else:
            # Ours again at the peer's batch, right after its timed runs (closest in time; the two
            # interpreters cannot share interleaved rounds).
            after = measure({"after": (generate_fn(b, config), ())}, args.repeats, args.min_sample_s)["after"]
            ours = b / after["median_s"]
            ratio = ours / peer["levels_per_s"]
            print(f"{'':34s} {'levels/s':>12s} {'compile s':>10s}")
            theirs = f"paper authors (jax {peer['jax']})"
            print(f"{theirs:34s} {peer['levels_per_s']:12,.0f} {peer['compile_s']:10.1f}")
            print(f"{'ours (right after the peer)':34s} {ours:12,.0f} {after['compile_s']:10.1f}")
            print(f"ratio ours / theirs at batch {b}: {ratio:.1f}x", flush=True)
            result["reference"] = {
                "measured": True,
                **peer,
                "ours_after": {**after, **rate(b, after["median_s"])},
                "ours_levels_per_s": ours,
                "ratio": ratio,
            }

    info = result["machine"]
    device = info["device"].split(":")[0]
    out = args.out or RESULTS / f"generator_throughput_{device}_{info['cpu_count']}cpu.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"results written to {out}")
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
