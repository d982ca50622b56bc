"""Training throughput of the paper authors' own IPPO script (their repo's `baselines/CEC/ippo_general.py`).

Measures env-steps per second of their full `make_train` training loop (rollout + GAE + PPO epochs, as one
jitted `lax.scan` over updates) on Overcooked, with compile time reported separately:

* ``--mode cec``: procedurally generated kitchens (``ENV_KWARGS.random_reset: True``), i.e. their CEC run;
* ``--mode single``: the fixed ``--layout`` kitchen (``random_reset: False``).

Everything else comes from their ``baselines/CEC/config/ippo_final.yaml`` (``GRAPH_NET: False``,
``LSTM: True``, ``FC_DIM_SIZE``/``GRU_HIDDEN_DIM`` 128, ...), with ``NUM_ENVS``, ``NUM_STEPS`` and
``TOTAL_TIMESTEPS = updates * num_envs * num_steps`` overridden. Their function is AOT-compiled with
``jax.jit(train).lower(key).compile()`` (``compile_s``), then called ``--repeats`` times, blocking on each
result (``run_s``: the fastest call; ``run_s_all``: every call, the first one included).
Building ``make_train`` (which eagerly generates their held-out kitchen set) is timed as ``setup_s``. One
JSON line goes to stdout; all other output (their tqdm bars, warnings) goes to stderr. wandb runs disabled.

This script runs with the reference stack's interpreter, never with this project's venv, and does not import
the project's ``cec`` package. Set-up (Python 3.11 venv holding their pins jax/jaxlib 0.4.18, flax 0.7.4,
optax 0.1.7, chex 0.1.84, numpy 1.26.4, scipy 1.12.0), then the rest of their imports::

    git -C <mirror of KJha02/crossEnvCooperation> archive HEAD | tar -x -C /tmp/refcheckout
    /tmp/refvenv/bin/pip install hydra-core==1.3.2 omegaconf==2.3.0 wandb==0.16.2 distrax==0.1.5 \\
        jax-tqdm==0.2.2 tensorflow-probability==0.22.1
    /tmp/refvenv/bin/pip install -c pins.txt gymnax==0.0.6 safetensors==0.4.2   # pins.txt: the pins above

    /tmp/refvenv/bin/python benchmarks/peers/reference_train.py --repo /tmp/refcheckout \\
        --num-envs 64 --num-steps 100 --updates 3 --mode cec
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import sys
import time
from pathlib import Path
from typing import Any


def _load_config(repo: Path, args: argparse.Namespace) -> dict[str, Any]:
    """Their yaml, parsed as hydra would (OmegaConf, so `1e8` is a float), plus our overrides."""
    from omegaconf import OmegaConf

    config: dict[str, Any] = OmegaConf.to_container(  # type: ignore[assignment]
        OmegaConf.load(repo / "baselines" / "CEC" / "config" / "ippo_final.yaml")
    )
    config.update(
        ENV_NAME="overcooked",
        NUM_ENVS=args.num_envs,
        NUM_STEPS=args.num_steps,
        TOTAL_TIMESTEPS=args.updates * args.num_envs * args.num_steps,
        GRAPH_NET=False,
        LSTM=True,
        FC_DIM_SIZE=128,
        GRU_HIDDEN_DIM=128,
        WANDB_MODE="disabled",
    )
    config["ENV_KWARGS"].update(random_reset=args.mode == "cec", layout=args.layout)
    return config


def _parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repo", type=Path, required=True, help="checkout of KJha02/crossEnvCooperation")
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--num-steps", type=int, default=100)
    parser.add_argument("--updates", type=int, default=3)
    parser.add_argument("--mode", choices=("cec", "single"), default="cec")
    parser.add_argument("--layout", default="cramped_room_9")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=2, help="timed calls of the compiled train; best kept")
    return parser.parse_args()


def main() -> None:
    args = _parse_args()
    repo: Path = args.repo.resolve()
    os.environ.setdefault("WANDB_MODE", "disabled")
    os.environ.setdefault("WANDB_SILENT", "true")
    # Their script does `import jaxmarl` (the package in the checkout root) and lives in baselines/CEC.
    sys.path[:0] = [str(repo), str(repo / "baselines" / "CEC")]

    with contextlib.redirect_stdout(sys.stderr):
        import jax
        import wandb

        ippo = importlib.import_module("ippo_general")
        wandb.init(mode="disabled")  # their per-update io_callback calls wandb.log

        config = _load_config(repo, args)
        t0 = time.perf_counter()
        train = ippo.make_train(config)
        setup_s = time.perf_counter() - t0

        key = jax.random.PRNGKey(args.seed)
        t0 = time.perf_counter()
        compiled = jax.jit(train).lower(key).compile()
        compile_s = time.perf_counter() - t0

        run_times: list[float] = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(compiled(key))
            run_times.append(time.perf_counter() - t0)
    run_s = min(run_times)

    env_steps = args.updates * args.num_envs * args.num_steps
    result = {
        "compile_s": round(compile_s, 3),
        "run_s": round(run_s, 3),
        "run_s_all": [round(t, 3) for t in run_times],
        "env_steps": env_steps,
        "env_steps_per_s": round(env_steps / run_s, 1),
        "num_envs": args.num_envs,
        "num_steps": args.num_steps,
        "updates": args.updates,
        "mode": args.mode,
        "layout": args.layout,
        "setup_s": round(setup_s, 3),
        "jax_version": jax.__version__,
        "devices": [str(d) for d in jax.devices()],
    }
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
