"""`cec cluster check CONFIG`: a `ray up` cluster config checked before any machine is started.

Ray's own schema (`ray/autoscaler/ray-schema.json`, after Ray fills in its provider defaults) plus what this
project needs on the nodes: the project installed by the setup commands, and Redis and the level server
started on the head node. Every problem is a `ConfigError` naming the field and the fix.
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path
from typing import Any

import yaml

from cec.config import ConfigError

EXAMPLE = "cluster/config.yaml (cloud) or cluster/config.local.yaml (your own machines)"


def check_cluster_config(path: str | Path) -> dict:
    """The validated config (with Ray's defaults filled in) of a `ray up` YAML file."""
    p = Path(path)
    try:
        raw = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise ConfigError(f"cannot read cluster config {p}: {err}") from err
    if not isinstance(raw, dict):
        raise ConfigError(f"cluster config {p} must be a YAML mapping; start from {EXAMPLE}")
    for key in ("cluster_name", "provider", "head_start_ray_commands", "setup_commands"):
        if key not in raw:
            raise ConfigError(f"cluster config {p} has no `{key}` field; add it (see {EXAMPLE})")
    import jsonschema
    from ray.autoscaler._private.util import prepare_config, validate_config

    try:
        config = prepare_config(copy.deepcopy(raw))
        validate_config(config)
    except jsonschema.ValidationError as err:
        where = ".".join(str(x) for x in err.absolute_path) or "the top level"
        raise ConfigError(f"cluster config {p}: {err.message} (at {where}); see {EXAMPLE}") from err
    except (ValueError, KeyError, RuntimeError) as err:
        raise ConfigError(f"cluster config {p}: {err}; see {EXAMPLE}") from err
    setup = " ".join(str(c) for c in raw.get("setup_commands", []))
    head = " ".join(str(c) for c in raw.get("head_start_ray_commands", []))
    needs = {
        "setup_commands must install this project (e.g. `cd ~/cec && make install`)": "install" in setup,
        "head_start_ray_commands must start Redis (`redis-server --port 6380 ...`)": "redis-server" in head,
        "head_start_ray_commands must start the level server (`cec level-server ...`)": "level-server"
        in head,
        "head_start_ray_commands must start Ray's head (`ray start --head ...`)": "--head" in head,
    }
    missing = [what for what, ok in needs.items() if not ok]
    if missing:
        raise ConfigError(f"cluster config {p}: " + "; ".join(missing) + f" (see {EXAMPLE})")
    return dict(config)


def add_subcommands(sub: Any) -> None:
    cluster = sub.add_parser("cluster", help="`ray up` cluster configs")
    cluster_sub = cluster.add_subparsers(dest="cluster_command", required=True)
    check = cluster_sub.add_parser(
        "check", help="validate a cluster config against Ray's schema and our needs"
    )
    check.add_argument("config", help="e.g. cluster/config.yaml")
    check.set_defaults(func=_cmd_check)


def _cmd_check(args: argparse.Namespace) -> int:
    config = check_cluster_config(args.config)
    kinds = ", ".join(config.get("available_node_types", {}))
    print(f"{args.config}: valid ({config['provider']['type']} provider; node types: {kinds})")
    return 0
