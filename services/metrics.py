"""Every Prometheus metric of the stack, named once (`cec_<component>_<what>_<unit>`, counters `_total`).

Services import the metric objects from here and never define their own, so dashboards and scrape tests
have one list to check against. Labels stay low-cardinality (an RPC name, a status code; never a level,
a seed or a client address). Metrics live in the default registry of the process that serves them.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

from prometheus_client import REGISTRY, Counter, Gauge, Histogram, Metric, start_http_server

from cec.config import ConfigError

# --- level server ------------------------------------------------------------------------------------------
LEVELS_GENERATED = Counter(
    "cec_level_server_levels_generated_total", "Levels produced by the generator (fresh, not replayed)"
)
LEVELS_SENT = Counter("cec_level_server_levels_sent_total", "Levels sent to clients, by RPC", ["rpc"])
HELDOUT_REJECTIONS = Counter(
    "cec_level_server_heldout_rejections_total",
    "Generator draws rejected because they matched a held-out evaluation kitchen (then redrawn)",
)
LEVELS_REPLAYED = Counter(
    "cec_level_server_levels_replayed_total", "Levels sent from the prioritized-level-replay buffer"
)
CURRICULUM_BUFFER = Gauge("cec_level_server_curriculum_buffer_levels", "Levels in the replay buffer")
ACTIVE_STREAMS = Gauge("cec_level_server_active_streams", "StreamLevels calls being served")
GENERATOR_CONFIGS = Gauge("cec_level_server_generator_configs", "Distinct generator configs compiled")
RPCS = Counter("cec_level_server_rpcs_total", "Finished RPCs by method and gRPC status code", ["rpc", "code"])
RPC_LATENCY = Histogram(
    "cec_level_server_rpc_duration_seconds",
    "Latency of unary RPCs, and time to the first batch of a stream",
    ["rpc"],
    buckets=(0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0, 60.0),
)


# --- learner (also exports what its actors report with each batch) ---------------------------------------
# Actors are short-lived Ray workers with no endpoint of their own: every trajectory batch carries the actor's
# stage timings and level-buffer state, and the learner's endpoint exports them (label `actor`: the actor's
# index, bounded by the configured number of actors). One scrape target covers all of training.
LEARNER_UPDATES = Counter("cec_learner_updates_total", "PPO updates applied by the learner")
LEARNER_ENV_STEPS = Counter("cec_learner_env_steps_total", "Joint env steps trained on (all seeds)")
LEARNER_STEPS_PER_SECOND = Gauge(
    "cec_learner_env_steps_per_second", "Joint env steps trained per second over the last update"
)
LEARNER_STAGE_SECONDS = Counter(
    "cec_learner_stage_seconds_total",
    "Wall time by stage: rollout (actors' jitted rollout), transfer (object store to learner), update (PPO), "
    "publish (weights into the object store), checkpoint, wait (learner idle for batches)",
    ["stage"],
)
LEARNER_POLICY_VERSION = Gauge("cec_learner_policy_version", "Version of the newest published weights")
LEARNER_POLICY_LAG = Histogram(
    "cec_learner_policy_lag_versions",
    "Policy versions between the weights a batch was collected with and the learner's current ones",
    buckets=(0, 1, 2, 3, 4, 6, 8, 16, 32),
)
LEARNER_BATCHES = Counter(
    "cec_learner_batches_total",
    "Trajectory batches received, by outcome: accepted, stale (older than max_policy_lag), "
    "dead_incarnation (from an actor process that has since been restarted)",
    ["outcome"],
)
LEARNER_BYTES_RECEIVED = Counter(
    "cec_learner_trajectory_bytes_total", "Bytes of trajectory batches fetched from the object store"
)
LEARNER_AGENT_STEPS_RECEIVED = Counter(
    "cec_learner_agent_steps_total", "Agent-steps (env steps x 2 seats) in the trajectory batches fetched"
)
LEARNER_EPISODE_RETURN = Gauge(
    "cec_learner_episode_return", "Mean team return of the episodes finished in the last update's batch"
)
LEARNER_SHAPED_RETURN = Gauge(
    "cec_learner_episode_shaped_return", "Mean shaped return (unscaled) of the episodes in the last update"
)
LEARNER_LOSS = Gauge("cec_learner_loss", "PPO diagnostics of the last update, by term", ["term"])
LEARNER_CHECKPOINTS = Counter("cec_learner_checkpoints_total", "Checkpoints written by the learner")
LEARNER_LAST_CHECKPOINT = Gauge(
    "cec_learner_last_checkpoint_timestamp_seconds", "Unix time of the learner's latest checkpoint"
)
LEARNER_RESTARTS = Gauge(
    "cec_learner_restarts", "Times the learner process was restarted in this run (0: never)"
)
LEARNER_REDIS_UP = Gauge("cec_learner_redis_up", "1 if the learner's last call to Redis succeeded, else 0")
LEARNER_CHECKPOINT_EVENTS_QUEUED = Gauge(
    "cec_learner_checkpoint_events_queued", "Checkpoint events waiting in the outbox for Redis to return"
)
ACTOR_RESTARTS = Counter(
    "cec_actor_restarts_total", "Actor processes restarted by Ray (new incarnations seen)"
)
ACTOR_LEVEL_BUFFER = Gauge(
    "cec_actor_level_buffer_levels", "Levels buffered locally by an actor (streamed kitchens)", ["actor"]
)
ACTOR_LEVEL_RECONNECTS = Counter(
    "cec_actor_level_server_reconnects_total", "Level-stream reconnections made by actors", ["actor"]
)
ACTOR_LEVELS_REUSED = Counter(
    "cec_actor_levels_reused_total",
    "Kitchens an actor replayed from its local pool because the level stream had none (server outage)",
    ["actor"],
)
ACTOR_ROLLOUT_SECONDS = Counter(
    "cec_actor_rollout_seconds_total", "Time actors spent in the jitted rollout", ["actor"]
)

# --- evaluator ------------------------------------------------------------------------------------------
EVALUATOR_CHECKPOINTS_SCORED = Counter(
    "cec_evaluator_checkpoints_scored_total", "Checkpoints whose evaluation finished (each counted once)"
)
EVALUATOR_EPISODES = Counter("cec_evaluator_episodes_total", "Episodes played by the evaluator")
EVALUATOR_PENDING = Gauge(
    "cec_evaluator_pending_checkpoints", "Checkpoint events read but not yet scored by this evaluator"
)
EVALUATOR_SCORE = Gauge(
    "cec_evaluator_return",
    "Mean team return of the newest scored checkpoint, by partner group (self_play for SP) and level set",
    ["partner_group", "level_set"],
)
EVALUATOR_SCORED_UPDATE = Gauge(
    "cec_evaluator_scored_update", "Training update of the newest checkpoint the evaluator scored"
)
EVALUATOR_DURATION = Histogram(
    "cec_evaluator_checkpoint_duration_seconds",
    "Time to score one checkpoint against every partner group and level set",
    buckets=(1, 2.5, 5, 10, 25, 50, 100, 250, 500, 1000, 2500),
)
EVALUATOR_FAILURES = Counter(
    "cec_evaluator_failures_total", "Checkpoint evaluations that failed (bad checkpoint, missing partner)"
)


# --- play (`cec play`, served on the app's own /metrics route) -----------------------------------------
PLAY_PARTICIPANTS = Counter("cec_play_participants_total", "Participants who joined a study")
PLAY_ROUNDS = Counter(
    "cec_play_rounds_total", "Rounds that ended, by outcome: completed or aborted", ["outcome"]
)
PLAY_ACTIVE_ROUNDS = Gauge("cec_play_active_rounds", "Rounds being played now")
PLAY_STEPS = Counter("cec_play_steps_total", "Game steps played, by mode (turn_based, real_time)", ["mode"])
PLAY_STEP_SECONDS = Histogram(
    "cec_play_step_duration_seconds",
    "Server time of one step: the jitted env step, the agent's next action, the next six branches, transfer",
    buckets=(0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 1.0),
)
PLAY_SURVEYS = Counter("cec_play_surveys_total", "Post-round surveys answered")
PLAY_AGENT_GAVE_WAY = Counter(
    "cec_play_agent_gave_way_total",
    "Steps whose agent action was the give-way rule's step aside (agent_gives_way_after), not its policy's",
)
PLAY_TICK_OVERRUNS = Counter(
    "cec_play_tick_overruns_total", "Real-time ticks that started late because the previous one overran"
)


#: which metric families each component's endpoint serves (every process imports them all; a process
#: serves only its own, so that Prometheus does not get a zero series of every metric from every job)
COMPONENTS: dict[str, tuple[str, ...]] = {
    "level_server": ("cec_level_server_",),
    "learner": ("cec_learner_", "cec_actor_"),
    "evaluator": ("cec_evaluator_",),
    "play": ("cec_play_",),
}


class ComponentRegistry:
    """The default registry seen through one component: its `cec_*` families and the process ones.

    `names`: only these samples (what `/metrics?name[]=a&name[]=b` asks for; unknown names select nothing).
    """

    def __init__(self, component: str | None, names: Iterable[str] | None = None) -> None:
        if component is not None and component not in COMPONENTS:
            raise ValueError(f"unknown metrics component {component!r}; one of {sorted(COMPONENTS)}")
        self.component = component
        self.prefixes = ("cec_",) if component is None else COMPONENTS[component]
        self.names = None if names is None else frozenset(names)

    def restricted_registry(self, names: Iterable[str]) -> ComponentRegistry:
        """The same view restricted to the samples `names` (prometheus_client calls this for `name[]`)."""
        return ComponentRegistry(self.component, names)

    def collect(self) -> Iterator[Metric]:
        for family in REGISTRY.collect():
            if family.name.startswith("cec_") and not family.name.startswith(self.prefixes):
                continue
            if self.names is None:
                yield family
                continue
            samples = [sample for sample in family.samples if sample.name in self.names]
            if samples:
                restricted = Metric(family.name, family.documentation, family.type, family.unit)
                restricted.samples = samples
                yield restricted


class MetricsEndpoint:
    """A running `/metrics` HTTP endpoint of one component (None: every metric); `close()` stops it."""

    def __init__(
        self, port: int, host: str = "127.0.0.1", component: str | None = None, key: str = "metrics_port"
    ) -> None:
        view = ComponentRegistry(component)
        try:
            self._server, self._thread = start_http_server(port, addr=host, registry=view)
        except OSError as err:  # the port, the service and the key that moves it, not a bare errno
            raise ConfigError(
                f"cannot serve {component or 'the'} metrics on {host}:{port} ({err.strerror or err}); move "
                f"them with {key}=PORT ({key}=0: a free one, -1: off), or stop what holds the port"
            ) from None
        self.host = host
        self.port: int = self._server.server_port  # the bound port (port 0 picks a free one)

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/metrics"

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
