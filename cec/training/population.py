"""FCP's partner population: frozen policies loaded from training runs' milestone checkpoints, checked to
fit the learner (`PartnerConfig.population`; the partner seat's play is `cec.training.partners`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from cec import checkpoints
from cec.agents.policy import load_policy
from cec.agents.zoo import ZooEntry
from cec.config import ConfigError
from cec.envs.task import Task
from cec.training.partners import PartnerConfig, Population


def _pick(milestones: list[Any], pick: str) -> Any:
    if pick.isdigit():
        found = [c for c in milestones if c.update == int(pick)]
        return found[0] if found else None
    index = {"first": 0, "middle": len(milestones) // 2, "last": len(milestones) - 1}[pick]
    return milestones[index] if milestones else None


def load_population(config: PartnerConfig, env: Any, network: Any, obs_shape: tuple[int, ...]) -> Population:
    """Loads FCP's population and checks every partner fits the learner (same game, observation shape
    and network). Raises `ConfigError` listing every offending entry, before any training starts."""
    params, names, problems = [], [], []
    for entry in config.population:
        milestones = [c for c in checkpoints.CheckpointStore(entry.run, keep_last=1).list() if c.milestone]
        if not milestones:
            problems.append(f"{entry.run}: no milestone checkpoints (is it a training run directory?)")
            continue
        for pick in entry.checkpoints:
            ckpt = _pick(milestones, pick)
            if ckpt is None:
                have = [c.update for c in milestones]
                problems.append(
                    f"{entry.run}: no milestone checkpoint {pick!r} (milestones at updates {have})"
                )
                continue
            seeds = entry.seeds or tuple(
                checkpoints.read_meta(ckpt.path).get("metadata", {}).get("seeds", ())
            )
            for seed in seeds:
                name = f"{Path(entry.run).name}/s{seed}/u{ckpt.update}"
                try:
                    policy = load_policy(ZooEntry(name=name, checkpoint=str(ckpt.path), seed=seed))
                except (checkpoints.CheckpointError, ConfigError, OSError, ValueError) as err:
                    problems.append(f"{name}: {err}")
                    continue
                why = []
                if policy.env.name != env.name:
                    why.append(f"plays {policy.env.name}, the learner {env.name}")
                elif Task.from_config(policy.env).obs_shape != obs_shape:
                    why.append(f"observes {Task.from_config(policy.env).obs_shape}, the learner {obs_shape}")
                if dataclasses.replace(policy.network, partner_history=0) != dataclasses.replace(
                    network, partner_history=0
                ):
                    why.append("has a different network (preset or widths) than the learner")
                if why:
                    problems.append(f"{name}: " + "; ".join(why))
                    continue
                params.append(policy.params)
                names.append(name)
    if problems or not params:
        raise ConfigError(
            "partner.population cannot be used:\n  - "
            + "\n  - ".join(problems or ["it resolves to no partner at all"])
            + "\nfix or drop those entries (each must be a milestone checkpoint of a run of the same game, "
            "observation shape and network)"
        )
    return Population(jax.tree.map(lambda *xs: jnp.asarray(np.stack(xs)), *params), tuple(names))
