"""Experiment tracking: a run's series as TensorBoard event files, optionally mirrored to Weights & Biases.

    tracker = Tracker(run_dir, config.tracking, name=config.run_name, role="train", resume_step=0)
    tracker.log_rows(rows)                        # the run's metrics rows: one point per column
    tracker.log(env_steps, {"eval/self_play/classic/return": 41.3})
    tracker.close()

Every writer of a run (the trainer or the distributed learner, role `train`; the evaluator, role
`evaluator`) writes event files of its own into the same folder, `<run directory>/tb/`, so TensorBoard
shows one run: `tensorboard --logdir <run directory>/tb`. The step of every point is the run's env steps
per seed, the `env_steps` of its metrics row or of the scored checkpoint.

A metrics row becomes one scalar per numeric column (not `update`, `env_steps`, `seed`), tagged
`<section>/<column>` (`SECTIONS`), with `/s<seed>` appended when the rows of one step come from more than
one seed. A resumed run hides the points written after the checkpoint it continues from, as its metrics
files drop those rows (TensorBoard's purge step).

W&B (`tracking.wandb=true`) is optional: the package is imported only then, and a missing one is a
`ConfigError` naming `pip install wandb`, raised by `TrackingConfig.check` before any work starts. Each
writer is a W&B run of its own (job type = role) in the group named after the training run, with
`env_steps` as the x axis.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cec.config import ConfigError
from cec.training.ppo import LossInfo

#: Run-directory folder of the event files.
TB_DIR = "tb"
#: Metrics-row columns that index a point rather than being a series.
INDEX_COLUMNS = ("update", "env_steps", "seed")
#: The TensorBoard section (the tag's first part) of the trainer's metrics-row columns; others: `train`.
SECTIONS: dict[str, str] = {
    **{name: "loss" for name in LossInfo._fields},
    "episodes": "episode",
    "mean_return": "episode",
    "mean_shaped_return": "episode",
    "normalised_return": "episode",
    "collisions_per_episode": "episode",
    "shaping_weight": "schedule",
    "learning_rate": "schedule",
    "env_steps_per_s": "perf",
}
WANDB_MODES = ("offline", "online")
ROLES = ("train", "evaluator")


@dataclass(frozen=True)
class TrackingConfig:
    """Where a run's series are written besides its metrics files.

    Attributes:
        tensorboard: write TensorBoard event files in `<run directory>/tb/`.
        wandb: mirror the same series to Weights & Biases (needs `pip install wandb`).
        wandb_project: the W&B project.
        wandb_entity: the W&B user or team (empty: W&B's default for the logged-in user).
        wandb_mode: `offline` (files in `<run directory>/wandb/`; upload later with `wandb sync`) or
            `online` (needs `wandb login` or WANDB_API_KEY).
    """

    tensorboard: bool = True
    wandb: bool = False
    wandb_project: str = "cec"
    wandb_entity: str = ""
    wandb_mode: str = "offline"

    def __post_init__(self) -> None:
        if self.wandb_mode not in WANDB_MODES:
            raise ConfigError(f"tracking.wandb_mode must be one of {WANDB_MODES}, got {self.wandb_mode!r}")
        if self.wandb and not self.wandb_project.strip():
            raise ConfigError("tracking.wandb_project is empty; name the W&B project (e.g. cec)")

    def check(self) -> None:
        """`ConfigError` when W&B is asked for and the package is not installed."""
        if self.wandb:
            _import_wandb()


def _import_wandb() -> Any:
    try:
        import wandb
    except ImportError as err:
        raise ConfigError(
            "tracking.wandb is true but the wandb package is not installed: pip install wandb "
            "(or pip install -e '.[wandb]'), or set tracking.wandb=false"
        ) from err
    return wandb


def describe(run_dir: str | Path, config: TrackingConfig) -> list[str]:
    """The lines telling where a run's series go and how to look at them (printed at start-up)."""
    lines = []
    if config.tensorboard:
        tb = Path(run_dir) / TB_DIR
        lines.append(f"TensorBoard events in {tb}; view them with: tensorboard --logdir {tb}")
    if config.wandb:
        where = Path(run_dir) / "wandb"
        if config.wandb_mode == "offline":
            lines.append(f"W&B (offline) mirror in {where}; upload it with: wandb sync {where}/offline-run-*")
        else:
            lines.append(f"W&B (online) mirror: project {config.wandb_project} (local files in {where})")
    return lines


def row_scalars(
    rows: Sequence[Mapping[str, Any]], sections: Mapping[str, str] | None = None
) -> dict[int, dict[str, float]]:
    """{env steps: {tag: value}} of metrics rows (see the module docstring; empty values are left out)."""
    sections = {**SECTIONS, **(sections or {})}
    seeds_at: dict[int, set] = {}
    for row in rows:
        seeds_at.setdefault(int(row["env_steps"]), set()).add(row.get("seed"))
    out: dict[int, dict[str, float]] = {}
    for row in rows:
        step = int(row["env_steps"])
        suffix = f"/s{row.get('seed')}" if len(seeds_at[step]) > 1 else ""
        points = out.setdefault(step, {})
        for column, value in row.items():
            if column in INDEX_COLUMNS or isinstance(value, bool) or not isinstance(value, int | float):
                continue
            points[f"{sections.get(column, 'train')}/{column}{suffix}"] = float(value)
    return out


class Tracker:
    """One writer of a run's series (see the module docstring).

    Args:
        run_dir: the run directory (`<run_dir>/<name>` of the training config).
        config: what to write.
        name: the training run's name (W&B run group).
        role: `train` (the trainer or the learner) or `evaluator`; names its event files and W&B job type.
        resume_step: the env steps a resumed run continues from: this role's points after it, written
            before the run stopped, are hidden. None: keep every point (the evaluator).
        run_config: the run's config as plain data (recorded by W&B).
    """

    def __init__(
        self,
        run_dir: str | Path,
        config: TrackingConfig,
        *,
        name: str,
        role: str = "train",
        resume_step: int | None = None,
        run_config: Mapping[str, Any] | None = None,
    ) -> None:
        if role not in ROLES:
            raise ValueError(f"role must be one of {ROLES}, got {role!r}")
        self.run_dir = Path(run_dir)
        self.config = config
        self.dir = self.run_dir / TB_DIR
        self.writer: Any = None
        self.wandb_run: Any = None
        if config.tensorboard:
            self.writer = self._open_tensorboard(role, resume_step)
        if config.wandb:
            try:
                self.wandb_run = self._open_wandb(name, role, run_config)
            except BaseException:
                self.close()
                raise

    def _open_tensorboard(self, role: str, resume_step: int | None) -> Any:
        from tensorboardX import SummaryWriter

        self.dir.mkdir(parents=True, exist_ok=True)
        files = list(self.dir.glob("*tfevents*"))
        earlier = any(f.name.endswith(f".{role}") for f in files)
        # tensorboardX names a file by the second and the host only (and truncates one of the same name):
        # the count of files before it and the process keep two writers' files apart, and those of one
        # second in the order they were started (TensorBoard reads a run's files in name order).
        return SummaryWriter(
            str(self.dir),
            filename_suffix=f".{len(files):05d}.{os.getpid()}.{role}",
            purge_step=resume_step + 1 if resume_step is not None and earlier else None,
            flush_secs=30,
        )

    def _open_wandb(self, name: str, role: str, run_config: Mapping[str, Any] | None) -> Any:
        wandb = _import_wandb()
        cfg = self.config
        run = wandb.init(
            project=cfg.wandb_project,
            entity=cfg.wandb_entity or None,
            name=name if role == "train" else f"{name} ({role})",
            group=name,
            job_type=role,
            dir=str(self.run_dir),
            mode=cfg.wandb_mode,
            config=dict(run_config or {}),
            reinit="create_new",  # a process may hold several (the evaluator: one per scored run)
            settings=wandb.Settings(console="off", silent=True, x_disable_stats=True),
        )
        run.define_metric("env_steps")
        run.define_metric("*", step_metric="env_steps")  # the x axis; steps may arrive out of order
        return run

    def log(self, step: int, values: Mapping[str, float | None]) -> None:
        """Writes `values` (tag -> number; None and non-finite values are left out) at env step `step`."""
        points = {k: float(v) for k, v in values.items() if v is not None and math.isfinite(float(v))}
        if not points:
            return
        if self.writer is not None:
            for tag, value in points.items():
                self.writer.add_scalar(tag, value, global_step=int(step))
            self.writer.flush()
        if self.wandb_run is not None:
            self.wandb_run.log({**points, "env_steps": int(step)})

    def log_rows(self, rows: Iterable[Mapping[str, Any]], sections: Mapping[str, str] | None = None) -> None:
        """Writes metrics rows (`row_scalars`), step by step."""
        for step, points in sorted(row_scalars(list(rows), sections).items()):
            self.log(step, points)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None
        if self.wandb_run is not None:
            self.wandb_run.finish()
            self.wandb_run = None

    def __enter__(self) -> Tracker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
