"""Several Ray nodes on this machine, each its own raylet and worker processes as on separate machines
(Ray's `ray.cluster_utils.Cluster`, over loopback): the learner pinned to the head and updating over two
(CPU) devices, one actor on each of two worker nodes, the level server streaming kitchens and the
evaluator scoring every checkpoint from Redis. Redis and the level server die (the actors train on, replaying
kitchens they have), then a worker node (its raylet and workers killed): the dead node's actor comes back on
the surviving node, Redis and the level server come back, and nothing is lost: every update, every
checkpoint event once and in order, every checkpoint scored."""

from __future__ import annotations

import dataclasses
import json
import signal
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

import pytest
from prometheus_client.parser import text_string_to_metric_families

ray = pytest.importorskip("ray")

from ray._private import state  # noqa: E402  (the GCS's actor table; `ray.util.state` needs the dashboard)
from ray.cluster_utils import Cluster  # noqa: E402

from cec.config import ConfigError, load_config  # noqa: E402
from cec.training.config import TrainConfig  # noqa: E402
from services.learner.config import DistributedConfig  # noqa: E402
from services.learner.driver import check_cluster, run_distributed  # noqa: E402
from services.processes import free_port  # noqa: E402
from services.service_process import ServiceProcess  # noqa: E402
from services.store import ControlPlane, LocalRedis  # noqa: E402

pytestmark = pytest.mark.timeout(600)
REPO = Path(__file__).resolve().parents[2]
UPDATES = 40


def _rows(run_dir: Path) -> list[dict]:
    path = run_dir / "metrics.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def _wait(what: str, ready: Any, timeout: float = 300, poll: float = 0.2) -> None:
    deadline = time.monotonic() + timeout
    while not ready():
        assert time.monotonic() < deadline, f"no {what} after {timeout} s"
        time.sleep(poll)


def _counter(url: str, name: str) -> float:
    with urllib.request.urlopen(url, timeout=10) as r:
        text = r.read().decode()
    return sum(s.value for f in text_string_to_metric_families(text) for s in f.samples if s.name == name)


def _actor_nodes() -> list[tuple[str, int]]:
    """(node id, restarts) of every live rollout actor."""
    actors = state.actors().values()
    alive = [a for a in actors if a["ActorClassName"] == "RolloutActor" and a["State"] == "ALIVE"]
    return sorted((a["Address"]["NodeID"], a["NumRestarts"]) for a in alive)


@pytest.mark.own_process  # hosts Ray's driver (tests/own_process.py)
def test_a_dead_nodes_actor_comes_back_on_another_node_and_nothing_is_lost(tmp_path: Path) -> None:
    redis = LocalRedis(tmp_path / "redis").start()
    done = threading.Event()
    port = free_port()

    def level_server() -> ServiceProcess:
        args = ["-m", "services.level_server", f"port={port}", "metrics_port=-1", "seed=1"]
        return ServiceProcess(
            "level server", args, tmp_path / "level_server.log", "level server ready on", 120
        )

    servers = {"level": level_server()}
    evaluator = ServiceProcess(
        "evaluator",
        ["-m", "services.evaluator", "--config", str(REPO / "tests/e2e/evaluator_small.yaml"),
         f"store.url={redis.config().url}", f"results_dir={tmp_path / 'results'}", "metrics_port=-1"],
        tmp_path / "evaluator.log",
        "evaluator ready",
        120,
    )  # fmt: skip
    cluster = Cluster(
        initialize_head=True,
        head_node_args={"num_cpus": 0, "resources": {"learner": 1}, "include_dashboard": False},
    )
    workers = [cluster.add_node(num_cpus=2, resources={"rollout": 2}) for _ in range(2)]
    try:
        ray.init(address=cluster.address, logging_level="WARNING")
        train = load_config(
            TrainConfig,
            None,
            ["algorithm=cec", "network=small", "network_overrides.conv_features=[]",
             "network_overrides.encoder_features=[32]", "network_overrides.lstm_features=0",
             "network_overrides.actor_features=[32]", "network_overrides.critic_features=[32]",
             "num_envs=8", "num_steps=64", f"total_env_steps={8 * 64 * UPDATES}", "updates_per_call=1",
             "env.overcooked.max_steps=16", "ppo.num_minibatches=2", "checkpoint.every_updates=4",
             f"checkpoint.keep_last={UPDATES}", "devices=2",
             f"run_dir={tmp_path}", "name=nodes"],
        )  # fmt: skip
        metrics_port = free_port()
        metrics = f"http://127.0.0.1:{metrics_port}/metrics"
        dist = DistributedConfig(
            num_actors=2,
            metrics_port=metrics_port,
            level_server=f"127.0.0.1:{port}",
            level_buffer_rollouts=2,  # drained by the outage below, so that the actors replay kitchens
            learner_resource="learner",
            actor_resource="rollout",
        )
        with pytest.raises(ConfigError, match="needs 2 unit.*ray start"):
            check_cluster(dataclasses.replace(dist, actor_resource="gpu_box"), ray.cluster_resources())
        run_dir = tmp_path / "nodes"
        seen: dict[str, Any] = {}

        def faults() -> None:
            try:
                _wait("two metrics rows", lambda: len(_rows(run_dir)) >= 2, poll=0.02)
                seen["before"] = _actor_nodes()  # SPREAD: one actor on each worker node
                redis.stop(kill=True)  # Redis crashes: checkpoint events go to the learner's outbox,
                servers["level"].proc.send_signal(signal.SIGKILL)  # the level server dies: actors replay,
                servers["level"].stop()
                outbox = ControlPlane(redis.config(), outbox_dir=run_dir)
                _wait("an event in the outbox", lambda: len(outbox.pending_outbox()) > 0, poll=0.02)
                _wait(
                    "kitchens replayed",
                    lambda: _counter(metrics, "cec_actor_levels_reused_total") > 0,
                    poll=0.02,
                )
                cluster.remove_node(workers[0], allow_graceful=False)  # and a worker node dies
                survivor = [workers[1].node_id] * 2
                _wait("both actors on the surviving node", lambda: [n for n, _ in _actor_nodes()] == survivor)
                seen["after"] = _actor_nodes()
                seen["restarts"] = _counter(metrics, "cec_actor_restarts_total")
                seen["reconnects"] = _counter(metrics, "cec_actor_level_server_reconnects_total")
                servers["level"] = level_server()  # both back: the actors' streams reconnect, and the
                redis.start()  # outbox is flushed at the learner's next heartbeat
            except BaseException as err:  # surfaced by the test
                seen["error"] = err
            done.wait(600)  # Redis dies with the thread that started it (`with_parent_death`)

        killer = threading.Thread(target=faults)
        killer.start()
        with open(tmp_path / "driver.log", "w") as log:
            code = run_distributed(train, dist, redis.config(), log_to=log)
        assert "error" not in seen, seen.get("error")
        assert "after" in seen, "the run ended before the faults were over"
        assert code == 0, (tmp_path / "driver.log").read_text()
        ids = [w.node_id for w in workers]
        assert [n for n, _ in seen["before"]] == sorted(ids), "the actors were spread over both worker nodes"
        assert seen["after"] == [(ids[1], 0), (ids[1], 1)], "the dead node's actor came back on the other"
        assert seen["restarts"] == 1, "the learner's metrics count the restart"
        assert seen["reconnects"] > 0, "the surviving actor's level stream kept trying to reconnect"
        assert [r["update"] for r in _rows(run_dir)] == list(range(1, UPDATES + 1))
        plane = ControlPlane.connect(redis.config())
        want = [f"nodes/update_{u:09d}" for u in range(0, UPDATES + 1, 4)]  # the initial policy's too
        events = [e.checkpoint_id for e in plane.list_checkpoints("nodes")]
        assert events == want, "every checkpoint event, once, in order"
        run = plane.get_run("nodes")
        assert run is not None and run.status == "finished"
        _wait("the evaluator scoring every checkpoint", lambda: all(plane.is_scored(c) for c in want), 240)
        plane.close()
    finally:
        done.set()
        ray.shutdown()
        cluster.shutdown()
        evaluator.stop()
        servers["level"].stop()
        redis.stop()
