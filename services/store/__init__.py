"""The control plane in Redis: run registry, checkpoint event stream, partner zoo, evaluation results.

One `ControlPlane` object wraps a `redis-py` client with plain methods that take and return named records;
the learner publishes checkpoints, the evaluator consumes them through a `CheckpointConsumer` (a Redis
Streams consumer group: at-least-once, acknowledged, pending work of a dead consumer reclaimed) and writes
results keyed by checkpoint, so a restarted evaluator never scores finished work again. `LocalRedis` runs a
real `redis-server` in a directory of its own (tests, and the single-machine `cec up`).

    plane = ControlPlane.connect(StoreConfig(), outbox_dir=run_dir)        # StoreError if unreachable
    plane.register_run("cec-s0", config=cfg_dict, algorithm="cec")
    plane.publish_checkpoint(CheckpointEvent(run_id="cec-s0", update=100, ...))  # never loses it
    consumer = plane.consumer(group="evaluator", name="evaluator-0")
    for msg in consumer.read(count=1, block_s=2.0):
        ...; plane.put_result(msg.event.checkpoint_id, "zoo", "classic", {"return_mean": 41.0})
        plane.mark_scored(msg.event.checkpoint_id); consumer.ack(msg)

Key schema (`P` is `StoreConfig.key_prefix`, `cec` by default; docs/control_plane.md has the long form):

    key                         type    contents                                       writer / readers
    P:runs                      zset    run id, scored by started_at                   learner / status, UI
    P:run:<run_id>              hash    run_id algorithm status started_at             learner / status,
                                        heartbeat_at config (YAML or JSON text)          evaluator
    P:checkpoints               stream  one entry per checkpoint: checkpoint_id run_id   learner / evaluator
                                        update env_steps path sha256 algorithm seed      (consumer groups)
                                        created_at
    P:checkpoint_ids            hash    checkpoint id -> stream entry id (dedupe)      learner (publish)
    P:consumed:<group>          set     checkpoint ids the group acknowledged          consumer
    P:dead:<group>              hash    stream entry id -> JSON {reason, consumer,     consumer / operators
                                        at, fields}: entries given up on
    P:zoo                       hash    partner name -> JSON PartnerRecord             zoo tools / evaluator
    P:result:<checkpoint_id>    hash    "<partner_group>|<level_set>" -> JSON          evaluator / report,
                                        EvalResult                                       dashboards
    P:results                   zset    checkpoint ids with results, by first write    evaluator / report
    P:scored                    hash    checkpoint id -> time its evaluation finished  evaluator

A checkpoint id is `<run_id>/update_<update, 9 digits>` (the checkpoint's directory under its run).
Publishing is one Lua script (index check + XADD + index write), so a retry or a re-publish of the same
checkpoint never adds a second stream entry. When Redis cannot be reached the event goes to a local
JSON-lines outbox (`<outbox_dir>/checkpoint_outbox.jsonl`, fsynced) and is written on the next successful
call, so a Redis restart loses no checkpoint event.

Modules (everything public is re-exported here, so `from services.store import X` works for all of them):

    config.py     StoreConfig, redact_url, StoreError, StoreUnavailableError, StoreKeyTypeError, the
                  environment variables
    records.py    RunRecord, CheckpointEvent, PublishResult, FlushResult, CheckpointMessage, PartnerRecord,
                  EvalResult, checkpoint_id
    client.py     RedisClient: the connection pool and the errors, for the plane, the consumer and the study
    plane.py      ControlPlane: its Lua scripts, the checkpoint outbox
    consumer.py   CheckpointConsumer: the consumer group
    local.py      LocalRedis: a local redis-server
"""

from services.store.client import RedisClient
from services.store.config import (
    DEFAULT_URL,
    ENV_PASSWORD,
    ENV_URL,
    INSTALL_HINT,
    MIN_REDIS_VERSION,
    StoreConfig,
    StoreError,
    StoreKeyTypeError,
    StoreUnavailableError,
    redact_url,
)
from services.store.consumer import CheckpointConsumer
from services.store.local import LocalRedis
from services.store.plane import DEFAULT_GROUP, OUTBOX_FILE, ControlPlane
from services.store.records import (
    RUN_STATUSES,
    CheckpointEvent,
    CheckpointMessage,
    EvalResult,
    FlushResult,
    PartnerRecord,
    PublishResult,
    RunRecord,
    checkpoint_id,
)

__all__ = [
    "CheckpointConsumer",
    "CheckpointEvent",
    "CheckpointMessage",
    "ControlPlane",
    "DEFAULT_GROUP",
    "DEFAULT_URL",
    "ENV_PASSWORD",
    "ENV_URL",
    "EvalResult",
    "FlushResult",
    "INSTALL_HINT",
    "LocalRedis",
    "MIN_REDIS_VERSION",
    "OUTBOX_FILE",
    "PartnerRecord",
    "PublishResult",
    "RedisClient",
    "RUN_STATUSES",
    "RunRecord",
    "StoreConfig",
    "StoreError",
    "StoreKeyTypeError",
    "StoreUnavailableError",
    "checkpoint_id",
    "redact_url",
]
