"""Joint env-steps per second of our Overcooked vs JaxMARL 0.2.0's, measured side by side in one run.

Method (as shared/BENCHMARKS.md): `jit` of a `lax.scan` over 128 steps of N `vmap`ped envs, uniform random
actions, both seats' observations and the rewards summed into the scan output so XLA cannot drop them,
auto-reset inside the step as each library does it (ours: from a per-env level buffer; JaxMARL: its own
`reset` on every step). Compile time is reported separately; throughput is the median of repeated runs.

    python benchmarks/env_throughput.py                  # N = 256, 1024, 4096; writes benchmarks/results/
    python benchmarks/env_throughput.py --n 1024 --repeats 3

Cases: Counter Circuit in a 9x9 frame for both libraries (the same kitchen), and Cramped Room (JaxMARL at
its native 4x5, ours in the 9x9 frame). Ours also runs a batch mixing all five classic kitchens.
"""

from __future__ import annotations

import argparse
import datetime
import json
import statistics
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from cec.envs import overcooked as oc
from cec.levels import Level, stack_levels

RESULTS = Path(__file__).parent / "results"


# How each step's observations are consumed so that XLA must compute them (the same for both libraries).
# A float32 sum reads every byte like a network's input conversion does; an int32 sum is much slower on
# XLA:CPU (it costs more than our whole env step) and compresses every ratio towards 1.
CONSUMERS: dict[str, Callable[[jax.Array], jax.Array]] = {
    "sum_f32": lambda obs: obs.sum(dtype=jnp.float32),
    "sum_i32": lambda obs: obs.sum(dtype=jnp.int32).astype(jnp.float32),
    "max": lambda obs: obs.max().astype(jnp.float32),
}


def ours_fn(levels: Level, n_envs: int, steps: int, consumer: str) -> Callable[[jax.Array], jax.Array]:
    """Scan of `steps` vmapped auto-reset steps; env i plays levels[i % K] (buffer of one level)."""
    params = oc.EnvParams()
    k = levels.grid.shape[0]
    per_env = jax.tree.map(lambda x: x[jnp.arange(n_envs) % k][:, None], levels)  # (N, 1, ...)

    def run(key: jax.Array) -> jax.Array:
        keys = jax.random.split(key, n_envs)
        first = jax.tree.map(lambda x: x[:, 0], per_env)
        _, state = jax.vmap(oc.reset, in_axes=(0, 0, None))(keys, first, params)

        def body(state: oc.EnvState, k: jax.Array) -> tuple[oc.EnvState, jax.Array]:
            k_act, k_step = jax.random.split(k)
            actions = jax.random.randint(k_act, (n_envs, 2), 0, oc.NUM_ACTIONS)
            out = jax.vmap(oc.step_autoreset, in_axes=(0, 0, 0, 0, None))(
                jax.random.split(k_step, n_envs), state, actions, per_env, params
            )
            consumed = CONSUMERS[consumer](out.obs) + out.reward.sum()
            return out.state, consumed

        _, consumed = jax.lax.scan(body, state, jax.random.split(key, steps))
        return consumed

    return run


def jaxmarl_fn(layout: Any, n_envs: int, steps: int, consumer: str) -> Callable[[jax.Array], jax.Array]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from jaxmarl.environments.overcooked import Overcooked

        env = Overcooked(layout=layout, max_steps=400)

    def run(key: jax.Array) -> jax.Array:
        _, state = jax.vmap(env.reset)(jax.random.split(key, n_envs))

        def body(state: Any, k: jax.Array) -> tuple[Any, jax.Array]:
            k_act, k_step = jax.random.split(k)
            a = jax.random.randint(k_act, (2, n_envs), 0, 6)
            obs, state, rew, _, _ = jax.vmap(env.step)(
                jax.random.split(k_step, n_envs), state, {"agent_0": a[0], "agent_1": a[1]}
            )
            both = jnp.stack([obs["agent_0"], obs["agent_1"]], axis=1)  # (N, 2, h, w, 26)
            consumed = CONSUMERS[consumer](both) + rew["agent_0"].sum()
            return state, consumed

        _, consumed = jax.lax.scan(body, state, jax.random.split(key, steps))
        return consumed

    return run


def jaxmarl_layout_9x9(level: Level) -> Any:
    """A JaxMARL layout dict of our (9x9-framed) level: the same kitchen for both libraries."""
    from flax.core.frozen_dict import FrozenDict

    from cec.levels import Tile

    grid = np.asarray(level.grid)
    flat = grid.reshape(-1)
    idx = lambda t: jnp.asarray(np.flatnonzero(flat == t))  # noqa: E731
    pos = np.asarray(level.agent_pos)
    return FrozenDict(
        {
            "height": 9,
            "width": 9,
            "wall_idx": jnp.asarray(np.flatnonzero(flat != Tile.FLOOR)),
            "agent_idx": jnp.asarray(pos[:, 0] * 9 + pos[:, 1]),
            "goal_idx": idx(Tile.GOAL),
            "plate_pile_idx": idx(Tile.PLATE_PILE),
            "onion_pile_idx": idx(Tile.ONION_PILE),
            "pot_idx": idx(Tile.POT),
        }
    )


def measure(
    fns: dict[str, Callable[[jax.Array], jax.Array]], n_envs: int, steps: int, repeats: int
) -> dict[str, dict[str, float]]:
    """Compiles each function, then times them in interleaved rounds (A B A B ...) so that drifting
    machine load affects all of them alike; reports the median time of each."""
    key = jax.random.PRNGKey(0)
    compiled, compile_s = {}, {}
    for name, fn in fns.items():
        t0 = time.perf_counter()
        compiled[name] = jax.jit(fn).lower(key).compile()
        compile_s[name] = time.perf_counter() - t0
        compiled[name](key).block_until_ready()  # warm-up
    times: dict[str, list[float]] = {name: [] for name in fns}
    for r in range(repeats):
        for name, c in compiled.items():
            t0 = time.perf_counter()
            c(jax.random.PRNGKey(r + 1)).block_until_ready()
            times[name].append(time.perf_counter() - t0)
    out = {}
    for name in fns:
        median = statistics.median(times[name])
        out[name] = {
            "compile_s": compile_s[name],
            "median_s": median,
            "steps_per_s": n_envs * steps / median,
        }
    return out


def machine() -> dict[str, Any]:
    from apps.machine import machine_info

    return machine_info()


def git_rev() -> str:
    from cec.checkpoints import code_version

    return code_version(short=True)


def save_result(name: str, fields: dict[str, Any], out: Path | None, tag: str = "") -> Path:
    """Writes a benchmark's result JSON: its name, today's date, the commit and the machine, then `fields`,
    to `out` or to `results/<name>[_<tag>]_<device>_<cores>cpu.json`; prints and returns the path."""
    info = machine()
    result = {"benchmark": name, "date": datetime.date.today().isoformat(), "git": git_rev(), "machine": info}
    device = info["device"].split(":")[0]
    out = out or RESULTS / f"{name}{'_' + tag if tag else ''}_{device}_{info['cpu_count']}cpu.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({**result, **fields}, indent=2) + "\n")
    print(f"wrote {out}")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, nargs="+", default=[256, 1024, 4096], help="numbers of envs")
    ap.add_argument("--steps", type=int, default=128, help="scan length")
    ap.add_argument("--repeats", type=int, default=9, help="timed runs per case (median reported)")
    ap.add_argument(
        "--consumer",
        choices=sorted(CONSUMERS),
        default="sum_i32",
        help="how observations are consumed (default: int32 sum)",
    )
    ap.add_argument("--no-peer", action="store_true", help="skip JaxMARL")
    ap.add_argument("--out", type=Path, default=None, help="results JSON (default: benchmarks/results/)")
    args = ap.parse_args(argv)

    peer = not args.no_peer
    if peer:
        try:
            import jaxmarl  # noqa: F401
        except ImportError:
            print(
                "jaxmarl not installed (pip install -e .[peers]); measuring ours only",
                file=sys.stderr,
            )
            peer = False

    from jaxmarl.environments.overcooked import overcooked_layouts as jm_layouts  # type: ignore

    cc, cr = oc.classic_level("counter_circuit"), oc.classic_level("cramped_room")
    Maker = Callable[[int], Callable[[jax.Array], jax.Array]]
    cases: list[tuple[str, Maker, Maker | None]] = [
        (
            "counter_circuit 9x9 (same kitchen)",
            lambda n: ours_fn(stack_levels([cc]), n, args.steps, args.consumer),
            lambda n: jaxmarl_fn(jaxmarl_layout_9x9(cc), n, args.steps, args.consumer),
        ),
        (
            "cramped_room (jaxmarl native 4x5)",
            lambda n: ours_fn(stack_levels([cr]), n, args.steps, args.consumer),
            lambda n: jaxmarl_fn(jm_layouts["cramped_room"], n, args.steps, args.consumer),
        ),
        (
            "5 classic kitchens mixed",
            lambda n: ours_fn(stack_levels(list(oc.classic_levels().values())), n, args.steps, args.consumer),
            None,
        ),
    ]
    rows = []
    print(
        f"{'case':38s} {'N':>5s} {'ours steps/s':>14s} {'jaxmarl steps/s':>16s} {'ratio':>7s} "
        f"{'compile ours/jm':>16s}",
        flush=True,
    )
    for name, make_ours, make_peer in cases:
        for n in args.n:
            fns = {"ours": make_ours(n)}
            if peer and make_peer is not None:
                fns["jaxmarl"] = make_peer(n)
            m = measure(fns, n, args.steps, args.repeats)
            row: dict[str, Any] = {"case": name, "n_envs": n, "steps": args.steps, **m}
            ours = m["ours"]
            line = f"{name:38s} {n:5d} {ours['steps_per_s']:14,.0f}"
            if "jaxmarl" in m:
                theirs = m["jaxmarl"]
                row["ratio"] = ours["steps_per_s"] / theirs["steps_per_s"]
                line += (
                    f" {theirs['steps_per_s']:16,.0f} {row['ratio']:6.2f}x "
                    f"{ours['compile_s']:7.1f}/{theirs['compile_s']:.1f}s"
                )
            else:
                line += f" {'-':>16s} {'-':>7s} {ours['compile_s']:7.1f}/-"
            print(line, flush=True)
            rows.append(row)

    info = machine()
    result = {
        "benchmark": "env_throughput",
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "git": git_rev(),
        "machine": info,
        "method": "jit(scan of vmap(step with auto-reset)), random actions, obs consumed + reward summed",
        "consumer": args.consumer,
        "repeats": args.repeats,
        "rows": rows,
    }
    device = info["device"].split(":")[0]
    out = args.out or RESULTS / f"env_throughput_{device}_{info['cpu_count']}cpu_{args.consumer}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"results written to {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
