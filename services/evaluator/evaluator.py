"""The evaluator as a plain object: checkpoint events in, cross-play results out (Redis, files, metrics).

    with Evaluator(config) as ev:          # connects to Redis, joins the consumer group
        ev.poll_once()                     # reads one checkpoint event (if any), scores it, acknowledges it
        ev.serve(stop_event)               # ... until `stop_event` is set

Scoring a checkpoint (`score`): each of its seeds plays, on each level set of its game, with itself
(`self_play`) and with every zoo partner (both seat orders, `cec.evaluation.crossplay` with common random
numbers). The work is stored in *parts*, one per (partner group, level set): the part's episodes go to a
staging file, then its summary to Redis (`put_result`, keyed by checkpoint, group and level set). Parts
already in Redis are never played again, so a restart resumes a half-scored checkpoint where it stopped.
When every part is stored, the staging files are merged into `<results_dir>/<run_id>/eval/update_<N>.csv`
(the canonical long table of `cec.evaluation.results`, written to a temporary file and renamed), the
checkpoint is marked scored, the gauges move, the scores go into the run's TensorBoard events (below), and
only then is the event acknowledged. A redelivered event of a scored checkpoint is acknowledged without work.

TensorBoard: a checkpoint's results are written into its own run's events, `<run directory>/tb/` (the run
directory holds the checkpoint: `<run>/checkpoints/update_<N>`), by a writer of the evaluator's own
(`cec.training.tracking.Tracker`, role `evaluator`) at the checkpoint's env steps, as
`eval/<partner group>/<level set>/<metric>` (`TRACKED_METRICS`); the W&B mirror too when the run has one.
The run's recorded `tracking` config decides; a failure to write is logged and changes nothing else.

A checkpoint that cannot be loaded (missing, corrupt, replaced since its event, a config this code cannot
read) is a failure: logged, counted (`cec_evaluator_failures_total`), recorded as the result
(`failed`, `checkpoint`) with the reason, and acknowledged, so the stream moves on. Any other error leaves
the event unacknowledged: it is delivered again after `store.claim_idle_s`, and given up on (dead-lettered
by the consumer group) after `store.max_deliveries` deliveries.

Size: the `Evaluator` is one consume-score-acknowledge loop whose restart and exactly-once rules read
best in one place; the level sets it alone uses sit above it. A part's summary and the checkpoint's result
table are the library's (`cec.evaluation.checkpoint_results`).
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

from cec import checkpoints
from cec.agents.policy import Policy, load_policy, resolve_checkpoint
from cec.agents.zoo import ZooEntry
from cec.config import ConfigError, from_dict
from cec.evaluation.checkpoint_results import SUMMARY_METRICS, ResultFiles, summarize
from cec.evaluation.crossplay import EvalLevels, crossplay, eval_levels
from cec.evaluation.results import (
    EpisodeTable,
    SkippedEntry,
    empty_table,
)
from cec.training.tracking import Tracker, TrackingConfig
from services.evaluator.config import (
    CROSS_PLAY,
    FAILED_GROUP,
    FAILED_LEVEL_SET,
    SELF_PLAY,
    EvaluatorConfig,
    LevelSetConfig,
)
from services.evaluator.partners import PartnerZoo, ZooSnapshot, names_in
from services.metrics import (
    EVALUATOR_CHECKPOINTS_SCORED,
    EVALUATOR_DURATION,
    EVALUATOR_EPISODES,
    EVALUATOR_FAILURES,
    EVALUATOR_PENDING,
    EVALUATOR_SCORE,
    EVALUATOR_SCORED_UPDATE,
)
from services.store import CheckpointEvent, CheckpointMessage, ControlPlane, EvalResult, StoreError

log = logging.getLogger("cec.evaluator")

#: A stored result's values written to the run's TensorBoard events: result key -> tag's last part.
TRACKED_METRICS = {**{f"{m}_mean": m for m in SUMMARY_METRICS}, "return_sem": "return_sem"}
#: Runs whose writers are kept open (the least recently used one beyond is closed; reopened when needed).
OPEN_TRACKERS = 8


class Outcome(NamedTuple):
    """What handling one checkpoint event did.

    Attributes:
        checkpoint_id: the checkpoint.
        status: `scored` (finished now), `already_scored` (a redelivery: nothing done), `failed` (the
            checkpoint cannot be scored; recorded and acknowledged), `ignored` (a run outside `runs`),
            `abandoned` (a stop request; stored parts kept, event left pending) or `error` (unexpected; the
            event stays pending and is delivered again later).
        computed: parts played and stored by this call, as `<partner_group>|<level_set>`.
        reused: parts found already stored (a resumed checkpoint).
        results: the checkpoint's results in Redis afterwards (scored and already_scored).
        error: the reason, for failed and error.
        seconds: wall time of the call.
    """

    checkpoint_id: str
    status: str
    computed: tuple[str, ...] = ()
    reused: tuple[str, ...] = ()
    results: tuple[EvalResult, ...] = ()
    error: str = ""
    seconds: float = 0.0


class AbandonedError(Exception):
    """A stop was requested while a checkpoint was being scored; its unfinished part was dropped."""


# ---------------------------------------------------------------------------------------------------------
# LEVEL SETS
# ---------------------------------------------------------------------------------------------------------


def level_set_levels(spec: LevelSetConfig) -> EvalLevels:
    """The levels of a level set (`eval_levels`), cut to its first `max_levels`."""
    try:
        levels = eval_levels(spec.env, spec.levels)
    except ConfigError as err:
        raise ConfigError(f"level set {spec.name!r}: {err}") from err
    n = spec.max_levels
    if n and len(levels.names) > n:
        cut = levels.levels
        levels = EvalLevels(levels.names[:n], _take(cut, n))
    return levels


def _take(tree: Any, n: int) -> Any:
    return jax.tree.map(lambda x: x[:n], tree)


# ---------------------------------------------------------------------------------------------------------
# THE EVALUATOR
# ---------------------------------------------------------------------------------------------------------


class Evaluator:
    """Scores checkpoints from the event stream against the zoo; stores results; exports metrics.

    Args:
        config: the service's config.
        plane: a connected control plane to use (None: connect to `config.store`; closed by `close()`).

    Raises `StoreError` when Redis cannot be reached and `ConfigError` for a bad zoo manifest or level set,
    before any event is read.
    """

    def __init__(self, config: EvaluatorConfig, plane: ControlPlane | None = None) -> None:
        self.config = config
        self._own_plane = plane is None
        self._trackers: dict[Path, Tracker | None] = {}  # run directory -> its writer (None: not tracked)
        self.plane = plane if plane is not None else ControlPlane.connect(config.store)
        try:
            self.zoo = PartnerZoo(config, self.plane)
            self.levels = {s.name: level_set_levels(s) for s in config.level_sets}
            self.consumer = self.plane.consumer(
                config.consumer_group, config.consumer_name, from_start=config.from_start
            )
        except BaseException:
            self.close()
            raise
        self._retry: CheckpointMessage | None = None
        self._gauges: set[tuple[str, str]] = set()

    def close(self) -> None:
        for tracker in self._trackers.values():
            if tracker is not None:
                tracker.close()
        self._trackers.clear()
        if self._own_plane:
            self.plane.close()

    def __enter__(self) -> Evaluator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- the loop -----------------------------------------------------------------------------------------

    def serve(self, stop: threading.Event) -> None:
        """Scores checkpoints as their events arrive until `stop` is set. Redis outages are waited out
        (with backoff); no checkpoint failure ends the loop."""
        delay = 0.5
        while not stop.is_set():
            try:
                self.poll_once(stop=stop)
                delay = 0.5
            except StoreError as err:
                log.warning("control plane: %s; retrying in %.1f s", err, delay)
                stop.wait(delay)
                delay = min(2 * delay, 30.0)

    def poll_once(self, block_s: float | None = None, stop: threading.Event | None = None) -> list[Outcome]:
        """Reads one checkpoint event (waiting up to `block_s`, default `poll_s`) and handles it.

        An event whose handling was cut short by a Redis failure is handled again first. Raises
        `StoreError` when Redis fails (the event is kept for the next call)."""
        if self._retry is not None:
            messages, self._retry = [self._retry], None
        else:
            wait = self.config.poll_s if block_s is None else block_s
            messages = self.consumer.read(count=1, block_s=wait)
        return [self.handle(m, stop) for m in messages]

    def handle(self, message: CheckpointMessage, stop: threading.Event | None = None) -> Outcome:
        """Scores the event's checkpoint (unless done before) and acknowledges the event once its results
        are stored. See `Outcome.status` for what can happen."""
        event = message.event
        cid = event.checkpoint_id
        EVALUATOR_PENDING.set(1)
        try:
            if self.config.runs and event.run_id not in self.config.runs:
                log.info("ignoring %s: run %s is not in `runs`", cid, event.run_id)
                self.consumer.ack(message)
                return Outcome(cid, "ignored")
            try:
                outcome = self.score(event, stop=stop, keepalive=self._keepalive(message))
            except AbandonedError:
                log.info("stop requested: left %s unfinished (stored parts are kept and resumed)", cid)
                return Outcome(cid, "abandoned")
            except StoreError:
                self._retry = message
                raise
            except Exception as err:  # a bug or an exhausted resource: the event is delivered again later
                log.exception("scoring %s failed; its event stays pending and is retried later", cid)
                EVALUATOR_FAILURES.inc()
                return Outcome(cid, "error", error=f"{type(err).__name__}: {err}")
            try:
                self.consumer.ack(message)
            except StoreError:
                self._retry = message  # done and stored: the retry finds it scored and only acknowledges
                raise
            return outcome
        finally:
            EVALUATOR_PENDING.set(0)

    def _keepalive(self, message: CheckpointMessage) -> Callable[[], None]:
        """Keeps a long job's event from being reclaimed by another consumer (at most every claim_idle/4)."""
        every = self.config.store.claim_idle_s / 4
        last = [time.monotonic()]

        def touch() -> None:
            if time.monotonic() - last[0] >= every:
                self.consumer.touch(message)
                last[0] = time.monotonic()

        return touch

    # --- scoring ------------------------------------------------------------------------------------------

    def score(
        self,
        event: CheckpointEvent,
        *,
        stop: threading.Event | None = None,
        keepalive: Callable[[], None] | None = None,
    ) -> Outcome:
        """Scores one checkpoint against self-play and the zoo on its game's level sets; stores every part
        not stored yet, writes the result table and marks the checkpoint scored (see the module docstring).

        Raises `AbandonedError` if `stop` is set before it finishes (between compiled calls), `StoreError` if
        Redis fails; a checkpoint that cannot be loaded gives a `failed` outcome.

        Long because it is one checkpoint's whole scoring, in the order a restart resumes it (load, each part
        played or found stored, the table, the mark).
        """
        cid = event.checkpoint_id
        t0 = time.perf_counter()
        if self.plane.is_scored(cid):
            log.info("%s was scored before; nothing to do", cid)
            return Outcome(cid, "already_scored", results=tuple(self.plane.get_results(cid)))
        try:
            seeds = self.load_checkpoint(event)
        except (checkpoints.CheckpointError, ConfigError, OSError, ValueError) as err:
            return self._fail(event, f"{type(err).__name__}: {err}", t0)
        env = seeds[0].env.name
        level_sets = self.config.level_sets_of(env)
        if not level_sets:
            names = [s.name for s in self.config.level_sets]
            return self._fail(
                event,
                f"it plays {env} and no level set does (level sets: {names}); add one with env: {env}",
                t0,
            )
        zoo = self.zoo.snapshot().for_game(env)
        own = [SELF_PLAY] if self.config.self_play else []
        own += [CROSS_PLAY] if self.config.cross_play and len(seeds) > 1 else []
        groups = own + zoo.groups()
        files = (
            ResultFiles(self.config.results_dir, event.run_id, event.update)
            if self.config.results_dir
            else None
        )
        log.info(
            "scoring %s (%s): %d seed(s); partner groups %s; level sets %s",
            cid,
            event.path,
            len(seeds),
            groups,
            [s.name for s in level_sets],
        )
        computed: list[str] = []
        reused: list[str] = []
        for spec in level_sets:
            if stop is not None and stop.is_set():
                raise AbandonedError
            stored = {g: self.plane.has_result(cid, g, spec.name) for g in groups}
            todo = [
                g for g in groups if not stored[g] or (files is not None and files.needs_rows(g, spec.name))
            ]
            reused += [f"{g}|{spec.name}" for g in groups if g not in todo]
            if not todo:
                continue
            partners = [p.policy for p in zoo.partners if p.group in todo]
            within = "all" if CROSS_PLAY in todo else "self" if SELF_PLAY in todo else ""
            if partners or within:
                table = self._play(seeds, partners, spec, within, stop, keepalive)
            else:  # only groups none of whose partners can play
                table = empty_table()
            for group in todo:
                part = self._part(table, group, zoo)
                if files is not None:
                    files.write_part(group, spec.name, part)
                if stored[group]:
                    log.warning(
                        "%s: replayed %s on %s for the results file only (its result was stored, its "
                        "episodes were in no file)",
                        cid,
                        group,
                        spec.name,
                    )
                    continue
                kind = group if group in (SELF_PLAY, CROSS_PLAY) else "partners"
                metrics = summarize(part, _label(event), kind=kind)
                metrics.update(_event_info(event, self.config))
                self.plane.put_result(cid, group, spec.name, metrics)
                computed.append(f"{group}|{spec.name}")
                log.info(
                    "%s %s on %s: return %s over %d episode(s)",
                    cid,
                    group,
                    spec.name,
                    _fmt(metrics["return_mean"]),
                    metrics["episodes"],
                )
        if files is not None:
            path = files.finish()
            log.info("%s: result table %s", cid, path)
        results = self.plane.get_results(cid)
        if files is not None:
            rows = [
                (r.partner_group, r.level_set, r.metrics) for r in results if r.partner_group != FAILED_GROUP
            ]
            files.record(event.update, event.env_steps, rows)
        self.plane.mark_scored(cid)
        seconds = time.perf_counter() - t0
        EVALUATOR_CHECKPOINTS_SCORED.inc()
        EVALUATOR_DURATION.observe(seconds)
        self._publish(event.update, results)
        self._track(event, results)
        log.info(
            "scored %s in %.1f s (%d part(s) computed, %d already stored)",
            cid,
            seconds,
            len(computed),
            len(reused),
        )
        return Outcome(cid, "scored", tuple(computed), tuple(reused), tuple(results), "", seconds)

    def load_checkpoint(self, event: CheckpointEvent) -> list[Policy]:
        """One policy per seed of the event's checkpoint (named `<checkpoint id>/s<seed>`, labelled
        `<run_id>@<update>`). `CheckpointError` if it is missing, corrupt, or replaced since the event."""
        path = Path(event.path)
        if not path.exists():
            raise checkpoints.CheckpointError(
                f"checkpoint {path} is missing (deleted by the run's keep-last-N before it was scored, or "
                "not on this machine's file system)"
            )
        path = resolve_checkpoint(path)
        meta = checkpoints.read_meta(path)
        if meta.get("sha256") != event.sha256:
            raise checkpoints.CheckpointError(
                f"checkpoint {path} was replaced after its event was published (state SHA-256 "
                f"{str(meta.get('sha256'))[:12]}..., the event says {event.sha256[:12]}...)"
            )
        config = meta.get("config", {})
        seeds = meta.get("metadata", {}).get("seeds")
        if not seeds:
            first = int(config.get("seed", event.seed))
            seeds = [first + i for i in range(int(config.get("num_seeds", 1)))]
        label = _label(event)
        return [load_policy(ZooEntry(f"{event.checkpoint_id}/s{s}", str(path), label, int(s))) for s in seeds]

    def _play(
        self,
        seeds: Sequence[Policy],
        partners: Sequence[Policy],
        spec: LevelSetConfig,
        within: str,
        stop: threading.Event | None,
        keepalive: Callable[[], None] | None,
    ) -> EpisodeTable:
        """The checkpoint's seeds with each other (`within`: `all`, each with itself and every other seed;
        `self`, each with itself; '': neither) and each seed with every partner (both seats) on the level
        set: one table."""
        cfg = self.config

        def progress(message: str) -> None:
            log.debug("%s: %s", spec.name, message)
            if stop is not None and stop.is_set():
                raise AbandonedError
            if keepalive is not None:
                keepalive()

        steps = spec.max_steps or cfg.play.max_steps
        tables = []
        if within:
            eval_config = dataclasses.replace(cfg.play, levels=spec.levels, pairs=within, max_steps=steps)
            tables.append(crossplay(list(seeds), self.levels[spec.name], eval_config, progress=progress))
        for policy in seeds if partners else ():
            eval_config = dataclasses.replace(
                cfg.play, levels=spec.levels, pairs=f"with:{policy.name}", max_steps=steps
            )
            table = crossplay([policy, *partners], self.levels[spec.name], eval_config, progress=progress)
            tables.append(table.select(table.policy_a != table.policy_b))  # with itself: played above
        EVALUATOR_EPISODES.inc(sum(len(t) for t in tables))
        return EpisodeTable.concat(tables)

    @staticmethod
    def _part(table: EpisodeTable, group: str, zoo: ZooSnapshot) -> EpisodeTable:
        """The rows and skipped entries of one partner group (or self-play)."""
        if group == SELF_PLAY:
            return table.select(table.policy_a == table.policy_b)
        names = names_in(zoo.partners, group)
        if group == CROSS_PLAY:  # the checkpoint's seeds with each other: neither side a zoo partner
            zoo_names = {p.policy.name for p in zoo.partners}
            own = ~np.isin(table.policy_a, list(zoo_names)) & ~np.isin(table.policy_b, list(zoo_names))
            return table.select(own & (table.policy_a != table.policy_b))
        rows = table.select(np.isin(table.policy_b, names))
        skipped: list[SkippedEntry] = [s for s in table.skipped if s.name in names]  # could not join
        skipped += [s.entry for s in zoo.skipped if s.group == group]  # could not be loaded
        return dataclasses.replace(rows, skipped=tuple(skipped))

    def _fail(self, event: CheckpointEvent, reason: str, t0: float) -> Outcome:
        cid = event.checkpoint_id
        log.error("cannot score %s: %s", cid, reason)
        EVALUATOR_FAILURES.inc()
        self.plane.put_result(
            cid, FAILED_GROUP, FAILED_LEVEL_SET, {"error": reason, **_event_info(event, self.config)}
        )
        return Outcome(cid, "failed", error=reason, seconds=time.perf_counter() - t0)

    # --- TensorBoard ----------------------------------------------------------------------------------------

    def _track(self, event: CheckpointEvent, results: Sequence[EvalResult]) -> None:
        """Writes a scored checkpoint's results into its run's TensorBoard events (module docstring)."""
        values = {
            f"eval/{r.partner_group}/{r.level_set}/{name}": r.metrics.get(key)
            for r in results
            if r.partner_group != FAILED_GROUP
            for key, name in TRACKED_METRICS.items()
            if isinstance(r.metrics.get(key), int | float)
        }
        try:
            tracker = self._tracker(Path(event.path), event.run_id)
            if tracker is not None and values:
                tracker.log(event.env_steps, values)
        except Exception as err:  # a full disk, a read-only run directory: the scores are stored anyway
            log.warning("%s: could not write its scores to TensorBoard: %s", event.checkpoint_id, err)

    def _tracker(self, path: Path, run_id: str) -> Tracker | None:
        """The evaluator's writer of the run holding checkpoint `path` (None: the run is not tracked or its
        directory is unknown), per the run's recorded `tracking` config."""
        if path.parent.name != "checkpoints":
            return None
        run_dir = path.parent.parent
        if run_dir in self._trackers:
            self._trackers[run_dir] = self._trackers.pop(run_dir)  # the most recently used, last
        else:
            if len(self._trackers) >= OPEN_TRACKERS:
                oldest = self._trackers.pop(next(iter(self._trackers)))
                if oldest is not None:
                    oldest.close()
            config = checkpoints.read_meta(path).get("config", {})
            try:
                tracking = from_dict(TrackingConfig, config.get("tracking", {}), where="tracking")
            except ConfigError as err:
                log.warning("run %s: unreadable tracking config (%s); writing TensorBoard only", run_id, err)
                tracking = TrackingConfig()
            if tracking.wandb:
                try:
                    tracking.check()
                except ConfigError as err:
                    log.warning("run %s: no W&B mirror of its scores: %s", run_id, err)
                    tracking = dataclasses.replace(tracking, wandb=False)
            tracked = tracking.tensorboard or tracking.wandb
            self._trackers[run_dir] = (
                Tracker(run_dir, tracking, name=run_id, role="evaluator") if tracked else None
            )
        return self._trackers[run_dir]

    # --- gauges -------------------------------------------------------------------------------------------

    def _publish(self, update: int, results: Sequence[EvalResult]) -> None:
        """Sets the return gauges to these results (a scored checkpoint's) and drops series it lacks."""
        now: set[tuple[str, str]] = set()
        for r in results:
            value = r.metrics.get("return_mean")
            if r.partner_group != FAILED_GROUP and isinstance(value, int | float):
                EVALUATOR_SCORE.labels(r.partner_group, r.level_set).set(value)
                now.add((r.partner_group, r.level_set))
        for labels in self._gauges - now:
            EVALUATOR_SCORE.remove(*labels)
        self._gauges = now
        EVALUATOR_SCORED_UPDATE.set(update)

    def restore_gauges(self) -> str | None:
        """Sets the gauges from the newest scored checkpoint in Redis (after a restart); returns its id."""
        scored = self.plane.list_scored()
        if not scored:
            return None
        cid = max(scored, key=lambda k: scored[k])
        event = self.plane.get_checkpoint(cid)
        self._publish(event.update if event is not None else 0, self.plane.get_results(cid))
        return cid


def _label(event: CheckpointEvent) -> str:
    """The algorithm label of a scored checkpoint's policies in result tables: `<run_id>@<update>`."""
    return f"{event.run_id}@{event.update}"


def _event_info(event: CheckpointEvent, config: EvaluatorConfig) -> dict[str, Any]:
    return {
        "run_id": event.run_id,
        "update": event.update,
        "env_steps": event.env_steps,
        "algorithm": event.algorithm,
        "path": event.path,
        "crn_seed": config.play.seed,
    }


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3f}"
