"""The self-describing half of `cec zoo export`: after the policies and `zoo.yaml` are written, the folder
gets its card (`card.md`: what the policies are, how they were trained, their evaluation) and its index
(`bundle.json`: every file's size and SHA-256, the card's facts), so that it loads by itself from a folder
or from any http(s) server that serves it (`cec.agents.bundle`; docs/evaluation.md).

The evaluation is a `cec eval` table of these policies (`--results`): per policy its episodes, its mean team
return with itself, with the bundle's other policies and with any partner, and the levels played. Without a
table the card says the policies were not evaluated with it.
"""

from __future__ import annotations

import datetime
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cec.agents.bundle import FORMAT, INDEX, MANIFEST, file_digest
from cec.config import ConfigError, read_user_yaml

CARD = "card.md"


def evaluation(results: Sequence[str | Path], names: Mapping[str, str]) -> dict[str, Any]:
    """Per exported policy (`names`: exported name -> its name in the tables), what `results` (`cec eval`
    tables) say of it; `ConfigError` when a table plays none of them."""
    from cec.evaluation.results import read_csv

    table = read_csv(list(results))
    a, b = table.policy_a.astype(str), table.policy_b.astype(str)
    ours = set(names.values())
    out: dict[str, Any] = {}
    for exported, name in names.items():
        rows = a == name
        if not rows.any():
            continue
        parts = {
            "self-play": rows & (b == name),
            "with the others": rows & (b != name) & np.isin(b, list(ours)),
        }
        parts["with any partner"] = rows & (b != name)
        out[exported] = {
            "episodes": int(rows.sum()),
            "levels": sorted({str(x) for x in table.level[rows]})[:20],
            **{k: _mean(table.returns[m]) for k, m in parts.items()},
        }
    if not out:
        raise ConfigError(
            f"--results {[str(r) for r in results]} play none of the exported policies "
            f"({sorted(ours)}); give the `cec eval` table of this zoo"
        )
    return {"tables": [Path(r).name for r in results], "policies": out}


def _mean(x: np.ndarray) -> dict[str, float] | None:
    if not len(x):
        return None
    sem = float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")
    return {"mean": float(x.mean()), "sem": sem, "episodes": int(len(x))}


def write_bundle(out_dir: Path, source: str, new_evaluation: dict[str, Any] | None) -> Path:
    """Writes `out_dir/card.md` and `out_dir/bundle.json` for the policies `out_dir/zoo.yaml` names (the
    evaluation of policies exported before into the same folder is kept); returns the index's path."""
    from cec import checkpoints

    manifest = read_user_yaml(out_dir / MANIFEST, "zoo manifest", 1 << 20, "cec.agents.zoo.ZOO_MAX_BYTES")
    entries = [e for e in manifest["policies"] if isinstance(e, Mapping) and "checkpoint" in e]
    old = _old_index(out_dir)
    evaluated = {
        **old.get("evaluation", {}).get("policies", {}),
        **(new_evaluation or {}).get("policies", {}),
    }
    tables = sorted({*old.get("evaluation", {}).get("tables", []), *(new_evaluation or {}).get("tables", [])})
    policies = []
    for e in entries:
        meta = checkpoints.read_meta(out_dir / e["checkpoint"])
        config = meta.get("config", {})
        policies.append(
            {
                **{
                    k: e[k]
                    for k in ("name", "algorithm", "seed", "env", "layout", "env_steps", "sha256")
                    if k in e
                },
                "network": config.get("network", ""),
                "network_overrides": config.get("network_overrides") or {},
                "total_env_steps": config.get("total_env_steps"),
                "code_version": meta.get("metadata", {}).get("code_version", ""),
            }
        )
    evaluation = {
        "tables": tables,
        "policies": {p["name"]: evaluated[p["name"]] for p in policies if p["name"] in evaluated},
    }
    (out_dir / CARD).write_text(_card(out_dir.name, source, policies, evaluation))
    files: dict[str, dict[str, Any]] = {}
    for name in [
        MANIFEST,
        CARD,
        *(f"{e['checkpoint']}/{f}" for e in entries for f in (checkpoints.STATE_FILE, checkpoints.META_FILE)),
    ]:
        size, sha = file_digest(out_dir / name)
        files[name] = {"bytes": size, "sha256": sha}
    index = {
        "format": FORMAT,
        "written": datetime.date.today().isoformat(),
        "policies": policies,
        "evaluation": evaluation,
        "files": files,
    }
    path = out_dir / INDEX
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(index, indent=1) + "\n")
    tmp.replace(path)
    return path


def _old_index(out_dir: Path) -> dict[str, Any]:
    try:
        data = json.loads((out_dir / INDEX).read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) and isinstance(data.get("evaluation"), dict) else {}


def _fmt(part: dict[str, float] | None) -> str:
    if part is None:
        return "—"
    sem = part["sem"]
    return f"{part['mean']:.1f}" + (f" ± {sem:.1f}" if sem == sem else "") + f" ({part['episodes']})"


def _card(title: str, source: str, policies: list[dict[str, Any]], evaluation: dict[str, Any]) -> str:
    lines = [
        f"# {title}: {len(policies)} polic{'y' if len(policies) == 1 else 'ies'}",
        "",
        f"Written by `cec zoo export` from `{source}` on {datetime.date.today().isoformat()}.",
        "Each policy is one seed's parameters (`<name>/state.msgpack`, no optimiser state) with the training",
        "config it came from (`<name>/meta.json`); `zoo.yaml` pins each by its SHA-256, `bundle.json` lists",
        "every file's size and SHA-256. Load it from this folder or from any http(s) server that serves it:",
        "",
        "    cec eval --zoo <this folder or its URL> --levels classic",
        "    cec play serve --zoo <this folder or its URL>",
        "",
        "## The policies",
        "",
        "| policy | algorithm | seed | game | levels | env steps | network | code | SHA-256 |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for p in policies:
        network = p["network"] + (" (overridden: see meta.json)" if p["network_overrides"] else "")
        lines.append(
            f"| {p['name']} | {p.get('algorithm', '')} | {p.get('seed', '')} | {p.get('env', '')} | "
            f"{p.get('layout', '')} | {p.get('env_steps', 0):,} | {network} | {p['code_version'] or '?'} | "
            f"{str(p.get('sha256', ''))[:12]} |"
        )
    lines += ["", "## Evaluation", ""]
    if not evaluation["policies"]:
        lines.append(
            "Not evaluated with this bundle: export with `--results <cec eval table>` to put figures here."
        )
    else:
        lines += [
            f"From `cec eval` ({', '.join(evaluation['tables'])}): team return per episode, mean ± standard "
            "error over episodes (episodes in brackets).",
            "",
            "| policy | self-play | with the others here | with any partner | levels |",
            "|---|---|---|---|---|",
        ]
        for name, e in evaluation["policies"].items():
            levels = ", ".join(e["levels"][:5]) + (", ..." if len(e["levels"]) > 5 else "")
            lines.append(
                f"| {name} | {_fmt(e['self-play'])} | {_fmt(e['with the others'])} | "
                f"{_fmt(e['with any partner'])} | {levels} |"
            )
    return "\n".join(lines) + "\n"
