"""A training run's directory (lock, config, resume, metrics files, checkpoints: `RunFiles`, shared with the
distributed learner) and `train`, the single-process run: the trainer's compiled calls through the update
loop of `cec.training.loop`, stopped gracefully on SIGINT/SIGTERM.

    cec train --config configs/train/cramped_room_ci.yaml     # = train(load_config(...))
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple, TextIO

import jax
import yaml

from cec import checkpoints
from cec.config import ConfigError, from_dict
from cec.signals import GracefulStop
from cec.training.config import TrainConfig, split_paths
from cec.training.loop import UpdateSource, out_of_memory, run_updates
from cec.training.metrics_file import MetricsWriter, write_atomic
from cec.training.tracking import Tracker, describe
from cec.training.trainer import Trainer, TrainState, UpdateMetrics

# ---------------------------------------------------------------------------------------------------------
# RUN DIRECTORY: config, metrics files, checkpoints, resume; and the single-process run
# ---------------------------------------------------------------------------------------------------------


class RunResult(NamedTuple):
    state: TrainState
    run_dir: Path
    updates_done: int
    interrupted: bool


def trains_as(written: dict, config: TrainConfig) -> bool:
    """Whether a checkpoint's recorded config (`written`) trains what `config` trains. Where the run lives
    (`run_dir`, `name`), where its series go (`tracking`), on how many devices it runs (`devices`: the
    same updates to float rounding) and how often it saves (`checkpoint.every_updates`, `keep_last`; its
    milestones count: FCP populations read them) are left out: a moved or copied run is the same run, and
    so is one that was written before `tracking` or `devices` existed or that saves more often now. Runs it
    reads (`partner.population`, `init_from`) that lie under its `run_dir` count by their place there: a
    zoo moved as a whole is the same zoo."""
    where = ("run_dir", "name", "tracking", "devices")
    cadence = ("every_updates", "keep_last")

    def what(cfg: dict) -> dict:
        kept = {k: v for k, v in cfg.items() if k not in where}
        if isinstance(kept.get("checkpoint"), dict):
            kept["checkpoint"] = {k: v for k, v in kept["checkpoint"].items() if k not in cadence}
        root = cfg.get("run_dir", "")
        if isinstance(kept.get("partner"), dict):
            population = [dict(e, run=_under(e["run"], root)) for e in kept["partner"].get("population", [])]
            kept["partner"] = dict(kept["partner"], population=population)
        if kept.get("init_from"):
            kept["init_from"] = ",".join(_under(p, root) for p in split_paths(kept["init_from"]))
        return kept

    return what(_as_read_now(written)) == what(config_dict(config))


def _as_read_now(written: dict) -> dict:
    """A checkpoint's recorded config as this version reads it: a setting added since it was written takes
    its default (off: what the run trained with then), so a code update does not strand every run written
    before it. As written when this version cannot read it (a setting since removed): not the same run."""
    try:
        return config_dict(from_dict(TrainConfig, written, where="the checkpoint's config"))
    except (ConfigError, TypeError, ValueError):
        return written


def _under(path: str, root: str) -> str:
    """`path` relative to `root` when it lies under it (the form a moved run directory keeps), else as is."""
    try:
        return str(Path(path).relative_to(root)) if root else path
    except ValueError:
        return path


def config_dict(config: TrainConfig) -> dict:
    """The config as plain data (YAML/JSON-safe; tuples become lists)."""
    return json.loads(json.dumps(dataclasses.asdict(config)))


#: A distributed run's launcher (`cec up`, `cec train --distributed`) records here the command that continues
#: the run; a run without it is a `cec train` run (`resume_command`).
RESUME_FILE = "logs/resume_command"
RESUME_FILE_MAX_BYTES = 4096


def resume_command(run_dir: str | Path) -> str:
    """The command that continues the run in `run_dir`: the one its launcher recorded (`RESUME_FILE`), else
    the single-process trainer's `cec train --resume RUN_DIR`."""
    try:
        with open(Path(run_dir) / RESUME_FILE, "rb") as f:
            recorded = f.read(RESUME_FILE_MAX_BYTES).decode(errors="replace").strip().splitlines()
    except OSError:
        recorded = []
    return recorded[0] if recorded else f"cec train --resume {run_dir}"


def record_resume_command(run_dir: str | Path, command: str) -> None:
    """Records `command` as the way to continue the run in `run_dir` (see `resume_command`)."""
    path = Path(run_dir) / RESUME_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, (command + "\n").encode())


class RunFiles:
    """A run directory's files: config, metrics rows, checkpoints (shared by the trainer and the learner).

    `open` takes the run directory's lock (`checkpoints.RunBusyError` when another process trains it),
    checks the directory (a run with checkpoints continues only with `resume`), loads the latest checkpoint
    into the trainer's state template (refusing one written with another config), trims metrics rows
    written after it, and returns the state and update count to continue from (None, 0: a new run).
    `tracker` opens the run's TensorBoard/W&B writer; `close` drops the lock. `opened` is all three as one
    context (what `train` and the learner use).
    """

    def __init__(self, config: TrainConfig) -> None:
        self.config = config
        self.run_dir = Path(config.run_dir) / config.run_name
        self.store = checkpoints.CheckpointStore(self.run_dir, config.checkpoint.keep_last)
        self.writer = MetricsWriter(self.run_dir)
        self.lock = checkpoints.RunLock(self.run_dir)
        total = config.num_updates
        self.milestones = sorted({min(total, max(0, round(f * total))) for f in config.checkpoint.milestones})
        self.metadata = {
            "algorithm": config.algorithm,
            "seeds": [config.seed + i for i in range(config.num_seeds)],
            "env": config.env.name,
            "levels": config.env.levels,
            "network": config.network,
            "code_version": checkpoints.code_version(),
            "jax_version": jax.__version__,
        }

    def open(self, template: TrainState, resume: bool, log: TextIO) -> tuple[TrainState | None, int]:
        self.lock.acquire()
        try:
            return self._open(template, resume, log)
        except BaseException:
            self.lock.release()
            raise

    def close(self) -> None:
        self.lock.release()

    @contextlib.contextmanager
    def opened(
        self, template: TrainState, resume: bool, log: TextIO
    ) -> Iterator[tuple[TrainState | None, int, Tracker]]:
        """`open` and the run's `tracker` after the update it continues from, both closed on leaving:
        (the state to continue from, its update, the tracker)."""
        loaded, done = self.open(template, resume, log)
        try:
            tracker = self.tracker(done)
            try:
                yield loaded, done, tracker
            finally:
                tracker.close()
        finally:
            self.close()

    def _open(self, template: TrainState, resume: bool, log: TextIO) -> tuple[TrainState | None, int]:
        if self.store.directories() and not resume:
            raise checkpoints.CheckpointError(
                f"{self.run_dir} already has checkpoints; continue it with `{resume_command(self.run_dir)}`, "
                "or give this run another name: name=NEW (or run_dir=DIR)"
            )
        latest = self.store.load_latest(template, log, self._count_problem)
        if latest is None:
            self.writer.truncate_after(0, log)  # rows of an attempt killed before its first checkpoint
            config_yaml = yaml.safe_dump(config_dict(self.config), sort_keys=False)
            write_atomic(self.run_dir / "config.yaml", config_yaml.encode())
            return None, 0
        state, meta = latest
        name = self.store.path(int(meta["update"])).name
        if not trains_as(meta["config"], self.config):
            raise checkpoints.CheckpointError(
                f"checkpoint {name} of {self.run_dir} was written with a different config; resume with the "
                f"run's own config ({self.run_dir / 'config.yaml'}) and no overrides"
            )
        done = int(meta["update"])
        self.writer.truncate_after(done, log)
        print(f"resuming {self.run_dir} from update {done} ({name})", file=log, flush=True)
        return state, done

    def _count_problem(self, meta: dict) -> str | None:
        """What is wrong with a checkpoint's counts for this run (None: nothing): more updates than the run
        has, or env steps that are not its updates' (a damaged or foreign `meta.json`)."""
        update, total, spu = int(meta["update"]), self.config.num_updates, self.config.steps_per_update
        if update > total:
            return f"update {update} is past the run's last update, {total}"
        if int(meta["env_steps"]) != update * spu:
            return f"env_steps {meta['env_steps']} are not update {update} x {spu} env steps per update"
        return None

    def due(self, prev: int, done: int) -> tuple[bool, bool]:
        """(a checkpoint is due after going from update `prev` to `done`, it is a milestone)."""
        every = self.config.checkpoint.every_updates
        crossed = any(prev < m <= done for m in self.milestones)
        return crossed or (every > 0 and done // every > prev // every), crossed

    def tracker(self, done: int) -> Tracker:
        """The run's `train` writer of TensorBoard events (and W&B), continuing after update `done`."""
        return Tracker(
            self.run_dir,
            self.config.tracking,
            name=self.config.run_name,
            role="train",
            resume_step=done * self.config.steps_per_update,
            run_config=config_dict(self.config),
        )

    def save(self, state: TrainState, update: int, milestone: bool) -> Path:
        return self.store.save(
            state,
            update=update,
            env_steps=update * self.config.steps_per_update,
            config=config_dict(self.config),
            metadata=self.metadata,
            milestone=milestone,
        )


def train(
    config: TrainConfig,
    *,
    resume: bool = False,
    max_updates: int | None = None,
    progress: bool = True,
    log: TextIO = sys.stderr,
) -> RunResult:
    """Runs (or resumes) a training run to its end, or until interrupted or `max_updates` more updates.

    The run directory `<run_dir>/<name>` gets `config.yaml`, `metrics.jsonl`, `metrics.csv`,
    `checkpoints/` and, per `config.tracking`, TensorBoard events in `tb/` (the metrics rows' values, at
    their env steps) and a W&B mirror. A run directory that already has checkpoints is only continued with
    `resume=True`.
    """
    config.tracking.check()  # W&B asked for and not installed: said before any work
    trainer = Trainer(config)
    trainer.load_partners()  # a bad population stops the run here, before any work
    files = RunFiles(config)
    with files.opened(trainer.state_template(), resume, log) as (loaded, done, tracker):
        for line in describe(files.run_dir, config.tracking):
            print(line, file=log, flush=True)
        state = trainer.init() if loaded is None else trainer.place(loaded)
        source = _InProcess(trainer, state, progress, log)
        with GracefulStop("finishing the current call, then saving a checkpoint") as flag:
            outcome = run_updates(
                source, files, tracker, done, max_updates=max_updates, stop=lambda: flag.stop,
                progress=progress, resume_hint=f"cec train --resume {files.run_dir}", log=log,
            )  # fmt: skip
    return RunResult(source.state(), files.run_dir, outcome.done, interrupted=outcome.stopped)


class _InProcess(UpdateSource):
    """`cec train`'s updates: the trainer's compiled calls, each `updates_per_call` updates of every seed,
    rollouts included, in this process."""

    def __init__(self, trainer: Trainer, state: TrainState, progress: bool, log: TextIO) -> None:
        self.trainer = trainer
        self.train_state = state
        self.updates_per_step = trainer.config.updates_per_call
        self.progress = progress
        self.log = log

    def step(self, done: int, n: int) -> UpdateMetrics:
        if self.progress and n not in self.trainer._calls:
            print(f"compiling the training call ({n} update(s) per call)...", file=self.log, flush=True)
        try:
            self.train_state, metrics = self.trainer.train_call(n)(self.train_state)
            jax.block_until_ready(self.train_state)
        except jax.errors.JaxRuntimeError as err:
            stop = out_of_memory(self.trainer.config, err, "the training call")
            if stop is None:
                raise
            raise stop from None
        return metrics

    def state(self) -> TrainState:
        return self.train_state
