"""The host loop of a training run: its directory (lock, config, resume), metrics rows and files,
checkpoints when due, progress lines and the graceful stop; `train` runs a `Trainer` through it, and the
distributed learner reuses `RunFiles`, `Progress` and `metrics_rows`.

    cec train --config configs/train/cramped_room_ci.yaml     # = train(load_config(...))
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple, TextIO

import jax
import yaml

from cec import checkpoints
from cec.signals import GracefulStop
from cec.training.config import TrainConfig, split_paths
from cec.training.ppo import LossInfo
from cec.training.tracking import Tracker, describe
from cec.training.trainer import Trainer, TrainState, UpdateMetrics

# ---------------------------------------------------------------------------------------------------------
# HOST LOOP: run directory, metrics files, checkpoints, progress, signals
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

    return what(written) == what(config_dict(config))


def _under(path: str, root: str) -> str:
    """`path` relative to `root` when it lies under it (the form a moved run directory keeps), else as is."""
    try:
        return str(Path(path).relative_to(root)) if root else path
    except ValueError:
        return path


def config_dict(config: TrainConfig) -> dict:
    """The config as plain data (YAML/JSON-safe; tuples become lists)."""
    return json.loads(json.dumps(dataclasses.asdict(config)))


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


class MetricsWriter:
    """Appends metrics rows to `metrics.jsonl` and `metrics.csv` in the run directory."""

    def __init__(self, run_dir: Path) -> None:
        self.jsonl = run_dir / "metrics.jsonl"
        self.csv = run_dir / "metrics.csv"

    def write(self, rows: list[dict]) -> None:
        if not rows:
            return
        with open(self.jsonl, "a") as f:
            for row in rows:
                f.write(json.dumps(row) + "\n")
        new = not self.csv.exists()
        with open(self.csv, "a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]), extrasaction="ignore")
            if new:
                writer.writeheader()
            writer.writerows(rows)

    def truncate_after(self, update: int) -> None:
        """Drops rows past `update` (written after the checkpoint a resumed run continues from)."""
        if self.jsonl.exists():
            keep = [ln for ln in self.jsonl.read_text().splitlines() if json.loads(ln)["update"] <= update]
            self.jsonl.write_text("".join(ln + "\n" for ln in keep))
        if self.csv.exists():
            with open(self.csv, newline="") as f:
                reader = csv.DictReader(f)
                fields = reader.fieldnames or []
                kept = [r for r in reader if int(r["update"]) <= update]
            with open(self.csv, "w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=fields)
                writer.writeheader()
                writer.writerows(kept)


class Progress:
    """One status line per call: updates, env steps, steps/s, mean return, ETA (to stderr)."""

    def __init__(self, total_updates: int, steps_per_update: int, stream: TextIO = sys.stderr) -> None:
        self.total = total_updates
        self.spu = steps_per_update
        self.stream = stream

    def show(self, done: int, sps: float, mean_return: float | None, eta_s: float) -> None:
        ret = "n/a" if mean_return is None else f"{mean_return:.2f}"
        line = (
            f"update {done}/{self.total} ({100 * done / self.total:5.1f}%) | "
            f"{_si(done * self.spu)}/{_si(self.total * self.spu)} steps | {_si(sps)} steps/s | "
            f"return {ret} | ETA {_duration(eta_s)}"
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
    path.write_text(command + "\n")


class RunFiles:
    """A run directory's files: config, metrics rows, checkpoints (shared by the trainer and the learner).

    `open` takes the run directory's lock (`checkpoints.RunBusyError` when another process trains it),
    checks the directory (a run with checkpoints continues only with `resume`), loads the latest checkpoint
    into the trainer's state template (refusing one written with another config), trims metrics rows
    written after it, and returns the state and update count to continue from (None, 0: a new run).
    `tracker` opens the run's TensorBoard/W&B writer; `close` drops the lock.
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

    def _open(self, template: TrainState, resume: bool, log: TextIO) -> tuple[TrainState | None, int]:
        if self.store.directories() and not resume:
            raise checkpoints.CheckpointError(
                f"{self.run_dir} already has checkpoints; continue it with `{resume_command(self.run_dir)}`, "
                "or give this run another name: name=NEW (or run_dir=DIR)"
            )
        latest = self.store.load_latest(template, log)
        if latest is None:
            self.writer.truncate_after(0)  # rows of an attempt killed before its first checkpoint
            (self.run_dir / "config.yaml").write_text(
                yaml.safe_dump(config_dict(self.config), sort_keys=False)
            )
            return None, 0
        state, meta = latest
        name = self.store.path(int(meta["update"])).name
        if not trains_as(meta["config"], self.config):
            raise checkpoints.CheckpointError(
                f"checkpoint {name} of {self.run_dir} was written with a different config; resume with the "
                f"run's own config ({self.run_dir / 'config.yaml'}) and no overrides"
            )
        done = int(meta["update"])
        self.writer.truncate_after(done)
        print(f"resuming {self.run_dir} from update {done} ({name})", file=log, flush=True)
        return state, done

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
    loaded, done = files.open(trainer.state_template(), resume, log)
    tracker = None
    try:
        tracker = files.tracker(done)
        for line in describe(files.run_dir, config.tracking):
            print(line, file=log, flush=True)
        return _train_loop(trainer, files, tracker, loaded, done, max_updates, progress, log)
    finally:
        if tracker is not None:
            tracker.close()
        files.close()


def _train_loop(
    trainer: Trainer,
    files: RunFiles,
    tracker: Tracker,
    loaded: TrainState | None,
    done: int,
    max_updates: int | None,
    progress: bool,
    log: TextIO,
) -> RunResult:
    config = files.config
    run_dir, writer = files.run_dir, files.writer
    state = trainer.init() if loaded is None else trainer.place(loaded)
    total = config.num_updates
    stop_at = total if max_updates is None else min(total, done + max_updates)
    per_call = config.updates_per_call
    meter = Progress(total, config.steps_per_update * config.num_seeds, log)
    if done == 0 and 0 in files.milestones:
        files.save(state, 0, milestone=True)
    interrupted = False
    with GracefulStop("finishing the current call, then saving a checkpoint") as flag:
        while done < stop_at:
            n = min(per_call, stop_at - done)
            if progress and n not in trainer._calls:
                print(f"compiling the training call ({n} update(s) per call)...", file=log, flush=True)
            call = trainer.train_call(n)
            t0 = time.perf_counter()
            state, metrics = call(state)
            jax.block_until_ready(state)
            dt = time.perf_counter() - t0
            sps = n * config.steps_per_update * config.num_seeds / dt
            rows = metrics_rows(config, done, metrics, sps)
            writer.write(rows)
            tracker.log_rows(rows)
            prev, done = done, done + n
            if progress:
                returns = [
                    r["mean_return"] for r in rows[-config.num_seeds :] if r["mean_return"] is not None
                ]
                meter.show(
                    done, sps, sum(returns) / len(returns) if returns else None, (total - done) * dt / n
                )
            due, crossed = files.due(prev, done)
            interrupted = flag.stop
            if due or done == stop_at or interrupted:
                files.save(state, done, milestone=crossed)
            if interrupted:
                print(
                    f"interrupted at update {done}; checkpoint saved. Continue with: "
                    f"cec train --resume {run_dir}",
                    file=log,
                    flush=True,
                )
                break
    return RunResult(state, run_dir, done, interrupted)
