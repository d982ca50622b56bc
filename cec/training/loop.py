"""The update loop of a training run, once for every way of running one: `cec train` runs the trainer's
compiled calls in its own process, the distributed learner gathers its actors' rollouts (in its process
with `LocalPool`, or Ray actors) and learns from them. Each hands the loop an `UpdateSource`, which says
only where the updates come from; the loop does the rest the same way for both:

    outcome = run_updates(source, files, tracker, done, max_updates=..., stop=flag.is_set)

Per step it runs the source's next updates, writes their metrics rows (`metrics.jsonl`, `metrics.csv`,
the tracker's events), shows a progress line (updates, env steps, steps/s, mean return, ETA to the run's
end at the pace since this process's first step, which compiles: that step's line has no ETA), and saves a
checkpoint when one is due: every `checkpoint.every_updates`, at a milestone, at the last update of this
process, and when it stops early. A stop asked for before a step runs none; one asked
for during a step ends the loop after it. Either way the last update is in a checkpoint.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, NamedTuple, Protocol, TextIO

import jax
import numpy as np

from cec.checkpoints import CheckpointStore
from cec.training.config import TrainConfig
from cec.training.ppo import LossInfo
from cec.training.tracking import Tracker
from cec.training.trainer import TrainState, UpdateMetrics


class RowWriter(Protocol):
    """Where a run's metrics rows go (`cec.training.run`'s writer of `metrics.jsonl` and `metrics.csv`)."""

    def write(self, rows: list[dict]) -> None: ...


class RunFolder(Protocol):
    """What the loop needs of a run's directory (`cec.training.run.RunFiles`, for `cec train` and the
    distributed learner alike): its config and milestone updates, where its metrics rows go, the checkpoint
    it kept last, when a checkpoint is due and how one is saved."""

    @property
    def config(self) -> TrainConfig: ...

    @property
    def milestones(self) -> list[int]: ...

    @property
    def writer(self) -> RowWriter: ...

    @property
    def store(self) -> CheckpointStore: ...

    def due(self, prev: int, done: int) -> tuple[bool, bool]: ...

    def save(self, state: TrainState, update: int, milestone: bool) -> Path: ...


class UpdateSource:
    """Where a run's updates come from; subclasses give `step` and `state`, and override the hooks they
    need (each does nothing here).

    `updates_per_step`: the most updates one `step` runs (the loop asks for fewer at the run's end)."""

    updates_per_step: int = 1

    def step(self, done: int, n: int) -> UpdateMetrics:
        """Runs `n` updates after update `done`; their metrics, with leading axes [seeds, n]."""
        raise NotImplementedError

    def state(self) -> TrainState:
        """The run's state after the last update, with a leading seed axis: what a checkpoint holds."""
        raise NotImplementedError

    def extra_columns(self) -> dict[str, Any]:
        """The source's own columns of this step's metrics rows (after the trainer's); asked once a step."""
        return {}

    def sections(self) -> Mapping[str, str]:
        """The TensorBoard section of each of the source's own columns (`Tracker.log_rows`)."""
        return {}

    def after_update(self, done: int, metrics: UpdateMetrics, sps: float) -> None:
        """Called after each step, once its rows are written and its checkpoint (if due) is saved."""

    def on_save(self, path: Path, seconds: float) -> None:
        """Called after each checkpoint, with its directory and the seconds writing it took."""


class Outcome(NamedTuple):
    """Where the loop ended: `done` updates, of the `stop_at` this process was to reach; `stopped`: a stop
    was asked for (before a step, or during one, the last one included)."""

    done: int
    stop_at: int
    stopped: bool


def run_updates(
    source: UpdateSource,
    files: RunFolder,
    tracker: Tracker,
    done: int,
    *,
    max_updates: int | None = None,
    stop: Callable[[], bool] = lambda: False,
    progress: bool = True,
    resume_hint: str | None = None,
    log: TextIO = sys.stderr,
) -> Outcome:
    """Runs the source's updates from update `done` to the run's end (or `max_updates` more, or a stop).

    `stop` is polled before and after every step. `resume_hint`: the command that continues the run,
    printed when it stops early (None: the caller says it). `progress`: a progress line per step, to
    `log`."""
    config = files.config
    total = config.num_updates
    stop_at = total if max_updates is None else min(total, done + max_updates)
    spu = config.steps_per_update * config.num_seeds  # env steps of one update, all seeds
    meter = Progress(total, spu, log) if progress else None
    if done == 0 and 0 in files.milestones:
        _save(source, files, 0, milestone=True)
    saved, stopped = done, False
    paced: tuple[int, float] | None = None  # (update, time) of the first step's line: the ETA's start
    while done < stop_at:
        if stop():  # asked before this step (the learner's driver may ask before the first)
            stopped = True
            break
        prev, done = done, done + min(source.updates_per_step, stop_at - done)
        t0 = time.perf_counter()
        metrics = source.step(prev, done - prev)
        diverged = nonfinite(config, prev, metrics)
        if diverged is not None:  # nothing of this step is written or saved: the last checkpoint stays
            raise NonFiniteError(f"{diverged}; {_kept(files)}")
        dt = time.perf_counter() - t0
        sps = (done - prev) * spu / dt
        rows = metrics_rows(config, prev, metrics, sps)
        extra = source.extra_columns()
        for row in rows:
            row.update(extra)
        files.writer.write(rows)
        tracker.log_rows(rows, source.sections())
        if meter is not None:
            now = time.perf_counter()
            eta = None if paced is None else (total - done) * (now - paced[1]) / (done - paced[0])
            meter.show(done, sps, _mean_return(rows, config.num_seeds), eta)
            paced = paced or (done, now)
        due, crossed = files.due(prev, done)
        stopped = stop()
        if due or done == stop_at or stopped:
            _save(source, files, done, milestone=crossed)
            saved = done
        source.after_update(done, metrics, sps)
        if stopped:
            break
    if stopped and saved != done:  # asked between two steps: the last one is saved all the same
        _save(source, files, done, milestone=False)
    if stopped and resume_hint is not None:
        print(
            f"interrupted at update {done}; checkpoint saved. Continue with: {resume_hint}",
            file=log,
            flush=True,
        )
    return Outcome(done, stop_at, stopped)


class RunStoppedError(ValueError):
    """The run stopped at an update it could not make, before writing or saving it (its last checkpoint
    kept); the message names the cause and what to change. `cec train` and `cec up` exit 2 with it."""


class NonFiniteError(RunStoppedError):
    """An update's loss or gradient norm was not finite."""


def out_of_memory(config: TrainConfig, err: Exception, what: str) -> RunStoppedError | None:
    """The error to stop with when `err` is the device running out of memory in `what` (XLA's
    RESOURCE_EXHAUSTED; the check before compiling counts the observations alone), naming the sizes to lower;
    None for any other error."""
    if not isinstance(err, jax.errors.JaxRuntimeError) or "RESOURCE_EXHAUSTED" not in str(err):
        return None
    return RunStoppedError(
        f"{what} does not fit in the memory of {jax.devices()[0].device_kind} ({str(err).splitlines()[0]}): "
        f"num_seeds {config.num_seeds} x num_envs {config.num_envs} x num_steps {config.num_steps} "
        "per update is too large here; lower num_envs, num_steps or num_seeds"
    )


def nonfinite(config: TrainConfig, first_update: int, metrics: UpdateMetrics) -> str | None:
    """What is not finite in the first update of `metrics` (leading axes [seeds, n]) whose loss or gradient
    norm is NaN or infinite, and the setting to look at; None when every one is finite."""
    host = jax.device_get(metrics.loss)
    total, grad = np.asarray(host.total_loss, np.float64), np.asarray(host.grad_norm, np.float64)
    bad = ~(np.isfinite(total) & np.isfinite(grad))
    if not bad.any():
        return None
    j = int(np.argmax(bad.any(axis=0)))  # the first update with a non-finite value
    s = int(np.argmax(bad[:, j]))
    values = {name: float(np.asarray(getattr(host, name))[s, j]) for name in LossInfo._fields}
    shown = ", ".join(f"{k}={v:.3g}" for k, v in values.items() if k in ("total_loss", "grad_norm"))
    return (
        f"update {first_update + j + 1} (seed {config.seed + s}) is not finite ({shown}): training stopped "
        f"there. Look at {suspect(config, values)}"
    )


def suspect(config: TrainConfig, values: Mapping[str, float]) -> str:
    """The setting most likely to have made an update not finite, from its loss terms (`values`: the
    `LossInfo` fields): the weight of a term that is itself not finite, else of the largest weighted term."""
    ppo = config.ppo
    rewards = f"the rewards of env.{config.env.name}"
    weighted = {  # setting -> (its value, the term it weighs)
        "ppo.teacher_coef": (ppo.teacher_coef, values["teacher_loss"]),
        "ppo.vf_coef": (ppo.vf_coef, values["value_loss"]),
        "ppo.ent_coef": (ppo.ent_coef, values["entropy"]),
        "ppo.partner_coef": (ppo.partner_coef, values["partner_loss"]),
        "ppo.lr": (ppo.lr, values["policy_loss"]),
    }
    broken = [k for k, (_, term) in weighted.items() if not math.isfinite(term)]
    if {"ppo.lr", "ppo.vf_coef"} <= set(broken):  # the network's outputs themselves: its parameters
        start = (
            f"init_from (the parameters it starts from: {config.init_from}), then "
            if config.init_from
            else ""
        )
        return f"{start}ppo.lr (here {ppo.lr:g}) and ppo.max_grad_norm (here {ppo.max_grad_norm:g})"
    if broken:
        name = broken[0]
    else:
        name = max(weighted, key=lambda k: abs(weighted[k][0] * weighted[k][1]) if k != "ppo.lr" else 0.0)
    value = weighted[name][0]
    also = f"{rewards} (the value loss grows with their square)" if name == "ppo.vf_coef" else "ppo.lr"
    return f"{name} (here {value:g}), then {also} and ppo.max_grad_norm (here {ppo.max_grad_norm:g})"


def _kept(files: RunFolder) -> str:
    kept = files.store.latest()
    if kept is None:
        return "no checkpoint was written before it (the run diverged before its first); start it again"
    return (
        f"its last good checkpoint is kept ({kept.path}, update {kept.update}); change that setting and "
        "train again under another name (name=NEW)"
    )


def _save(source: UpdateSource, files: RunFolder, update: int, milestone: bool) -> None:
    state = source.state()
    t0 = time.perf_counter()
    path = files.save(state, update, milestone)
    source.on_save(path, time.perf_counter() - t0)


def _mean_return(rows: list[dict], seeds: int) -> float | None:
    """The last update's mean return over its seeds (None: no episode ended in it)."""
    returns = [r["mean_return"] for r in rows[-seeds:] if r["mean_return"] is not None]
    return sum(returns) / len(returns) if returns else None


def metrics_rows(config: TrainConfig, first_update: int, metrics: UpdateMetrics, sps: float) -> list[dict]:
    """One row per (update, seed) from metrics with leading axes [S, n]."""
    host = jax.device_get(metrics)
    loss = host.loss
    rows = []
    s_count, n = host.episodes.shape
    for j in range(n):
        upd = first_update + j + 1
        for s in range(s_count):
            row: dict[str, Any] = {
                "update": upd,
                "env_steps": upd * config.steps_per_update,
                "seed": config.seed + s,
                "episodes": int(host.episodes[s, j]),
                "mean_return": _num(host.mean_return[s, j]),
                "mean_shaped_return": _num(host.mean_shaped_return[s, j]),
                "collisions_per_episode": _num(host.collisions_per_episode[s, j]),
                "shaping_weight": _num(host.shaping_weight[s, j]),
                "learning_rate": _num(host.learning_rate[s, j]),
                **{name: _num(getattr(loss, name)[s, j]) for name in LossInfo._fields},
                "env_steps_per_s": round(sps, 1),
            }
            if config.env.game.normalised_score:  # always a column, so the CSV header has it
                ret = row["mean_return"]
                row["normalised_return"] = None if ret is None else ret / (2 * config.env.params.max_steps)
            rows.append(row)
    return rows


def _num(x: Any) -> float | None:
    v = float(x)
    return None if math.isnan(v) else v


class Progress:
    """One status line per call: updates, env steps, steps/s, mean return, ETA (to stderr; `eta_s` None: not
    yet known, the line of a process's first step, which compiled: its time says nothing of the pace)."""

    def __init__(self, total_updates: int, steps_per_update: int, stream: TextIO = sys.stderr) -> None:
        self.total = total_updates
        self.spu = steps_per_update
        self.stream = stream

    def show(self, done: int, sps: float, mean_return: float | None, eta_s: float | None) -> None:
        ret = "n/a" if mean_return is None else f"{mean_return:.2f}"
        unknown = eta_s is None and done < self.total
        eta = "? (timed from the next update)" if unknown else _duration(eta_s or 0)
        line = (
            f"update {done}/{self.total} ({100 * done / self.total:5.1f}%) | "
            f"{_si(done * self.spu)}/{_si(self.total * self.spu)} steps | {_si(sps)} steps/s | "
            f"return {ret} | ETA {eta}"
        )
        print(line, file=self.stream, flush=True)


def _si(x: float) -> str:
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if abs(x) >= scale:
            return f"{x / scale:.2f}{unit}"
    return f"{x:.0f}"


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    s = int(seconds)
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"
