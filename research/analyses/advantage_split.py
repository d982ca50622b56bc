"""Where a scripted-partner run's policy gradient comes from: the advantages of its trained steps with the
cook and without it, from one checkpoint.

A run with `partner.kind: scripted` mixes episodes with Overcooked's scripted cook and self-play
episodes in one batch. This plays `--rollouts` rollouts of the checkpoint's first seed with the run's own
settings (the trainer's level draws, partner draws and GAE; the last rollout is measured, the ones before
it carry the envs into mid-episode as training does), then prints for each kind of step its share of the
batch, the mean and deviation of its advantages, and its mean value and return target. Advantages that
spread much wider in one kind carry most of the gradient once the loss normalises them together.

    python research/analyses/advantage_split.py runs/levers/scripted-both-s400 --update 320

(lever c2 of research/diary/reproduce_overcooked.md, "Levers for every kitchen").
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from cec import checkpoints
from cec.config import load_config
from cec.training.config import TrainConfig
from cec.training.ppo import make_batch
from cec.training.rollout import NUM_SEATS, rollout
from cec.training.trainer import Trainer


def split(run: Path, update: int, rollouts: int = 3) -> dict[str, dict[str, float]]:
    """{kind of step: its share of the batch and its advantages', values' and targets' statistics}."""
    cfg = load_config(TrainConfig, str(run / "config.yaml"), [])
    if cfg.partner.kind != "scripted":
        raise SystemExit(f"{run} trains with partner.kind {cfg.partner.kind!r}, not scripted")
    trainer = Trainer(cfg)
    state, _ = checkpoints.load(run / "checkpoints" / f"update_{update:09d}", trainer.state_template())
    seed0 = jax.tree.map(lambda x: x[0], state)
    levels = trainer.task.sample_levels(jax.random.PRNGKey(5), jnp.arange(cfg.num_envs), cfg.levels_per_env)
    play = jax.jit(
        lambda p, c, k: rollout(
            p, c, levels, k, task=trainer.task, network=trainer.network, env_params=trainer.env_params,
            num_steps=cfg.num_steps, partner=cfg.partner,
        )
    )  # fmt: skip
    carry = seed0.carry
    for i in range(rollouts):
        carry, traj = play(seed0.params, carry, jax.random.PRNGKey(10 + i))
    batch = make_batch(traj, jnp.float32(1.0), cfg.ppo.gamma, cfg.ppo.gae_lambda, mask_scripted_seat=True)
    with_cook = np.repeat(np.asarray(traj.partner_index) == 1, NUM_SEATS, axis=1)  # [T, 2E]
    trained = np.asarray(batch.weight) == 1
    adv, value, target = (np.asarray(x) for x in (batch.advantage, batch.value, batch.target))
    out = {}
    for name, rows in (("learner with the cook", trained & with_cook), ("self-play", ~with_cook)):
        out[name] = {
            "share": float(rows.mean()),
            "advantage_mean": float(adv[rows].mean()),
            "advantage_sd": float(adv[rows].std()),
            "value": float(value[rows].mean()),
            "target": float(target[rows].mean()),
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a `cec train` run directory with partner.kind scripted")
    parser.add_argument("--update", type=int, required=True, help="the checkpoint's update number")
    parser.add_argument("--rollouts", type=int, default=3, help="rollouts played; the last one is measured")
    args = parser.parse_args()
    result = split(args.run, args.update, args.rollouts)
    for name, s in result.items():
        print(
            f"{name}: {s['share']:.0%} of the batch | advantage {s['advantage_mean']:+.2f} "
            f"sd {s['advantage_sd']:.2f} | value {s['value']:.2f} | target {s['target']:.2f}"
        )
    print(json.dumps({"run": str(args.run), "update": args.update, "split": result}))


if __name__ == "__main__":
    main()
