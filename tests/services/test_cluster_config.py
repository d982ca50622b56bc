"""`ray up` configs: valid under Ray's own schema, and a broken one refused with the field named."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

pytest.importorskip("ray")

from cec.config import ConfigError  # noqa: E402
from services.cluster import check_cluster_config  # noqa: E402

CLUSTER = Path(__file__).resolve().parents[2] / "cluster"


@pytest.mark.parametrize("name", ["config.yaml", "config.local.yaml"])
def test_shipped_cluster_configs_pass_rays_schema(name: str) -> None:
    config = check_cluster_config(CLUSTER / name)
    assert config["head_node_type"] in config["available_node_types"]


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda c: c.pop("provider"), "provider"),
        (lambda c: c.pop("cluster_name"), "cluster_name"),
        (lambda c: c.update(max_workers="four"), "max_workers"),
        (lambda c: c.update(head_node_type="gpu"), "head_node_type"),
        (lambda c: c.update(head_start_ray_commands=["ray start --head"]), "Redis"),
    ],
)
def test_a_broken_cluster_config_is_refused_naming_the_field(tmp_path: Path, edit, match: str) -> None:  # type: ignore[no-untyped-def]
    config = yaml.safe_load((CLUSTER / "config.yaml").read_text())
    edit(config)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(config))
    with pytest.raises(ConfigError, match=match):
        check_cluster_config(path)


def test_the_learner_takes_a_gpu_when_given_one_and_the_gpu_head_installs_cuda(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    from services.learner.config import DistributedConfig
    from services.learner.driver import learner_options

    monkeypatch.delenv("JAX_PLATFORMS", raising=False)
    cpu, gpu = learner_options(DistributedConfig()), learner_options(DistributedConfig(learner_gpus=1))
    assert cpu["num_gpus"] == 0 and cpu["runtime_env"]["env_vars"]["JAX_PLATFORMS"] == "cpu"
    assert gpu["num_gpus"] == 1 and gpu["runtime_env"]["env_vars"]["JAX_PLATFORMS"] == ""  # JAX picks the GPU
    with pytest.raises(ConfigError, match="learner_gpus must be >= 0"):
        DistributedConfig(learner_gpus=-1)
    config = yaml.safe_load((CLUSTER / "config.yaml").read_text())
    assert any(".[cuda]" in c for c in config["head_setup_commands"])
