"""`cec status [RUN_DIR] [--watch [S]] [--json]`: how is my run doing, in one screen.

Everything comes from what the run already writes, so it also works for a finished or crashed run:

- the run directory: `config.yaml` (algorithm, env, budget), the last row of `metrics.jsonl` (update, env
  steps, steps/s, returns, entropy, policy lag), the newest checkpoint and its age;
- `logs/stack.json` and `logs/children.json`, written by a running `cec up`: whether the stack and each of
  its services still run, and the addresses of Redis and the services' metrics;
- the control plane (Redis, when the stack names it): the run's registry record and heartbeat, and the
  evaluator's latest scores per partner group and level set;
- the level server's and the learner's Prometheus endpoints: levels sent, active streams, the learner's
  policy version.

- the evaluator's training record (`<run>/eval/record.csv`): its scores per partner group and level set,
  also after the stack and its Redis have stopped.

Nothing here writes anywhere; a part that cannot be read is shown as such, never an error of the command.
Everything read is bounded: run files are regular files of at most `RUN_FILE_MAX_BYTES` (the end of
`metrics.jsonl`: `METRICS_TAIL_BYTES`), values of the wrong type are left out, metrics are fetched only from
http(s) URLs, at most `SCRAPE_MAX_BYTES` within `HTTP_DEADLINE_S` each, errors are clipped to `ERROR_CHARS`,
and `--json` prints strict JSON (a NaN is null).

Size: one screen's reading and rendering: each part of the run is a short reader and a short renderer of
the same dict, and they read best side by side.
"""

from __future__ import annotations

import argparse
import http.client
import json
import math
import os
import sys
import time
import urllib.parse
import urllib.request
from pathlib import Path
from typing import Any

from cec.config import ConfigError, open_user_file, read_user_json, read_user_yaml
from services.processes import ChildRecord

STACK_FILE = "logs/stack.json"
CHILDREN_FILE = "logs/children.json"
#: The longest one network read may block, and the most one endpoint may take in all (a server sending a
#: byte a second never holds the command longer).
HTTP_TIMEOUT_S = 2.0
HTTP_DEADLINE_S = 5.0
#: The largest metrics page read from an endpoint (a page is tens of kB).
SCRAPE_MAX_BYTES = 4 << 20
#: The largest run file read whole (`config.yaml`, `logs/stack.json`, `logs/children.json`: a few kB each).
RUN_FILE_MAX_BYTES = 1 << 20
#: How much of the end of `metrics.jsonl` is read for its last row (a row is about 1 kB).
METRICS_TAIL_BYTES = 65536
#: The longest error text shown for a part (a server's reply is never echoed whole).
ERROR_CHARS = 300


def write_stack_file(run_dir: Path, urls: dict[str, str], redis_needs_password: bool) -> Path:
    """Written by `cec up` once its services run (atomically): its pid, start time and addresses."""
    path = run_dir / STACK_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    info = {
        "owner": os.getpid(),
        "started_at": time.time(),
        "urls": urls,
        "redis_password": redis_needs_password,
    }
    tmp.write_text(json.dumps(info, indent=1))
    tmp.replace(path)
    return path


def find_run(root: Path) -> Path | None:
    """The newest run directory under `root` (the one whose metrics or stack file changed last); None when
    there is none."""
    marks = [
        p
        for pattern in ("*/metrics.jsonl", "*/*/metrics.jsonl", f"*/{STACK_FILE}")
        for p in root.glob(pattern)
    ]
    if not marks:
        return None
    newest = max(marks, key=lambda p: p.stat().st_mtime)
    return newest.parent.parent if newest.parent.name == "logs" else newest.parent


def collect(run_dir: Path, redis_url: str = "", now: float | None = None) -> dict[str, Any]:
    """The run's status as one JSON-able dict (see the module docstring)."""
    now = time.time() if now is None else now
    if not run_dir.is_dir():
        raise ConfigError(f"run directory {str(run_dir)!r} does not exist")
    out: dict[str, Any] = {"run_dir": str(run_dir), "run": run_dir.name, "at": now}
    out["config"] = _config(run_dir)
    out["progress"] = last_row(run_dir / "metrics.jsonl")
    out["checkpoint"] = _checkpoint(run_dir, now)
    stack = _stack(run_dir, now)
    out["stack"] = stack
    out["trainer"] = _trainer(run_dir, stack)
    urls = stack.get("urls", {})
    masked = stack.get("redis_password") and not redis_url  # the recorded URL has its password masked
    out["control_plane"] = _control_plane(run_dir.name, redis_url or urls.get("redis", ""), bool(masked), now)
    out["record"] = _record(run_dir)
    out["level_server"] = _scrape(
        urls.get("level server metrics", ""),
        {
            "levels_sent": "cec_level_server_levels_sent_total",
            "active_streams": "cec_level_server_active_streams",
            "curriculum_buffer": "cec_level_server_curriculum_buffer_levels",
        },
    )
    out["learner"] = _scrape(
        urls.get("learner metrics", ""),
        {"policy_version": "cec_learner_policy_version", "restarts": "cec_learner_restarts"},
    )
    return out


def _config(run_dir: Path) -> dict[str, Any]:
    path = run_dir / "config.yaml"
    try:
        data = read_user_yaml(path, "run config", RUN_FILE_MAX_BYTES, _setting("RUN_FILE_MAX_BYTES")) or {}
    except ConfigError as err:
        return {"error": f"no readable config.yaml: {_clip(str(err))}"}
    if not isinstance(data, dict):
        return {"error": f"{path} is not a mapping of fields (a {type(data).__name__})"}
    env: dict[str, Any] = data["env"] if isinstance(data.get("env"), dict) else {}
    return {
        "algorithm": _scalar(data.get("algorithm")),
        "env": _scalar(env.get("name")),
        "levels": _scalar(env.get("levels")),
        "total_env_steps": _count(data.get("total_env_steps")),
        "num_seeds": _count(data.get("num_seeds")),
    }


def last_row(path: Path) -> dict[str, Any]:
    """The last complete line of a JSON-lines file that is a JSON object (read from its end, however long
    the file), with its JSON scalars only (a list or object where a number belongs is left out)."""
    try:
        with open_user_file(path, "metrics file") as f:
            size = os.fstat(f.fileno()).st_size
            f.seek(max(0, size - METRICS_TAIL_BYTES))
            lines = f.read(METRICS_TAIL_BYTES).splitlines()
            written_at = os.fstat(f.fileno()).st_mtime
    except (ConfigError, OSError):
        return {}
    for line in reversed(lines):
        try:
            row = json.loads(line)
        except (json.JSONDecodeError, UnicodeDecodeError, RecursionError):
            continue  # a line being written
        if isinstance(row, dict):
            clean = {str(k): _scalar(v) for k, v in row.items() if _scalar(v) is not None}
            clean["written_at"] = written_at
            return clean
    return {}


def _scalar(value: Any) -> Any:
    """`value` if it is a string, bool or finite number; None otherwise (NaN, lists, objects)."""
    if isinstance(value, str | bool):
        return value
    if isinstance(value, int | float) and math.isfinite(value):
        return value
    return None


def _count(value: Any) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def _number(value: Any, default: float = 0.0) -> float:
    return float(value) if isinstance(value, int | float) and math.isfinite(value) else default


def _setting(name: str) -> str:
    return f"{__name__}.{name}"


def _clip(text: str) -> str:
    text = " ".join(text.split())
    return text if len(text) <= ERROR_CHARS else text[: ERROR_CHARS - 3] + "..."


def _checkpoint(run_dir: Path, now: float) -> dict[str, Any]:
    from cec.checkpoints import CheckpointStore

    dirs = CheckpointStore(run_dir, keep_last=1).directories()
    if not dirs:
        return {}
    newest = dirs[-1]
    return {"name": newest.name, "count": len(dirs), "age_s": now - newest.stat().st_mtime}


def _trainer(run_dir: Path, stack: dict[str, Any]) -> dict[str, Any]:
    """Whether a process trains the run now (the pid its lock file names runs, or its `cec up` does), and
    the command that continues it (`cec.training.run.resume_command`)."""
    from cec.checkpoints import LOCK_FILE
    from cec.training.run import resume_command

    try:
        with open_user_file(run_dir / LOCK_FILE, "lock file") as f:
            text = f.read(32).decode(errors="replace").strip()
    except (ConfigError, OSError):
        text = ""
    pid = int(text) if text.isdigit() else 0
    running = stack.get("state") == "running" or (pid > 0 and ChildRecord.running(pid))
    return {"pid": pid, "running": running, "continue_with": resume_command(run_dir)}


def _stack(run_dir: Path, now: float) -> dict[str, Any]:
    path = run_dir / STACK_FILE
    if not path.exists():
        return {"state": "none"}  # not a `cec up` run, or one that stopped cleanly
    try:
        info = read_user_json(path, "stack file", RUN_FILE_MAX_BYTES, _setting("RUN_FILE_MAX_BYTES"))
    except ConfigError as err:
        return {"state": "none", "error": _clip(str(err))}
    if not isinstance(info, dict):
        return {"state": "none", "error": f"{path} is not a JSON object (a {type(info).__name__})"}
    children = run_dir / CHILDREN_FILE
    record = ChildRecord(children).recorded() if _small_regular(children) else None
    owner = _count(info.get("owner")) or 0
    services = {str(c.get("name", "?")): bool(c["alive"]) for c in record[1]} if record else {}
    urls: dict[str, Any] = info["urls"] if isinstance(info.get("urls"), dict) else {}
    return {
        "state": "running" if owner > 0 and ChildRecord.running(owner) else "dead",
        "pid": owner,
        "up_s": now - _number(info.get("started_at"), now),
        "services": services,
        "urls": {str(k): v for k, v in urls.items() if isinstance(v, str)},
        "redis_password": bool(info.get("redis_password")),
    }


def _small_regular(path: Path) -> bool:
    """Whether `path` is a regular file of at most `RUN_FILE_MAX_BYTES` (what `ChildRecord` may read)."""
    try:
        with open_user_file(path, "run file") as f:
            return os.fstat(f.fileno()).st_size <= RUN_FILE_MAX_BYTES
    except (ConfigError, OSError):
        return False


def _control_plane(run_id: str, url: str, masked: bool, now: float) -> dict[str, Any]:
    if not url:
        return {}
    if masked:
        return {"error": f"Redis {url} needs its password: give --redis redis://:PASSWORD@host:port/0"}
    from services.store import ControlPlane, StoreConfig, StoreError

    config = StoreConfig(url=url, connect_timeout_s=HTTP_TIMEOUT_S, retries=0)
    try:
        plane = ControlPlane.connect(config)
    except (StoreError, ConfigError) as err:
        return {"error": f"Redis at {config.display_url} did not answer: {_clip(str(err))}"}
    try:
        out: dict[str, Any] = {"redis": config.display_url}
        run = plane.get_run(run_id)
        if run is not None:
            out["run_status"] = run.status
            out["heartbeat_age_s"] = now - run.heartbeat_at
        mine = {cid: at for cid, at in plane.list_scored().items() if cid.startswith(f"{run_id}/")}
        if mine:
            newest = max(mine, key=lambda cid: cid)  # update_<9 digits>: the name orders them
            out["scored"] = len(mine)
            out["latest_scored"] = newest
            out["scores"] = [
                {"partner_group": r.partner_group, "level_set": r.level_set, **_score(r.metrics)}
                for r in plane.get_results(newest)
            ]
        return out
    except StoreError as err:
        return {"error": f"Redis at {config.display_url}: {_clip(str(err))}"}
    finally:
        plane.close()


def _score(metrics: dict[str, Any]) -> dict[str, Any]:
    return {k: metrics[k] for k in ("return_mean", "return_sem", "episodes") if k in metrics}


def _scrape(url: str, names: dict[str, str]) -> dict[str, Any]:
    """Sums of the named Prometheus series at `url` (`{}` without a URL; `error` when it does not answer,
    is not an http(s) URL, or sends more than `SCRAPE_MAX_BYTES` or for longer than `HTTP_DEADLINE_S`)."""
    if not url:
        return {}
    from prometheus_client.parser import text_string_to_metric_families

    shown = _clip(url)
    try:
        text = _fetch(url).decode()
    except _FetchError as err:
        return {"error": f"{shown}: {err}"}
    except UnicodeDecodeError:
        return {"error": f"{shown} did not send UTF-8 text"}
    wanted = {v.removesuffix("_total"): k for k, v in names.items()}
    out: dict[str, Any] = {"up": True}
    try:
        for family in text_string_to_metric_families(text):
            key = wanted.get(family.name)
            if key is not None:
                out[key] = sum(s.value for s in family.samples if not s.name.endswith("_created"))
    except (ValueError, TypeError, IndexError) as err:
        return {"error": f"{shown} did not send Prometheus metrics ({_clip(str(err))})"}
    return out


class _FetchError(Exception):
    """A metrics endpoint that could not be read; the message says why (clipped)."""


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    """Redirects are not followed (one could lead to another scheme or host than `stack.json` names)."""

    def redirect_request(self, *args: Any, **kwargs: Any) -> None:
        return None


def _fetch(url: str) -> bytes:
    """The body of an http(s) `url`, read in at most `HTTP_DEADLINE_S` and `SCRAPE_MAX_BYTES`."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise _FetchError("not an http(s) URL; cec status reads metrics only over http(s)")
    deadline = time.monotonic() + HTTP_DEADLINE_S
    opener = urllib.request.build_opener(_NoRedirect)
    body = bytearray()
    try:
        with opener.open(url, timeout=HTTP_TIMEOUT_S) as response:
            while chunk := response.read1(65536):
                body += chunk
                if len(body) > SCRAPE_MAX_BYTES:
                    raise _FetchError(
                        f"sent more than {SCRAPE_MAX_BYTES:,} bytes ({_setting('SCRAPE_MAX_BYTES')})"
                    )
                if time.monotonic() > deadline:
                    raise _FetchError(
                        f"took longer than {HTTP_DEADLINE_S:g} s ({_setting('HTTP_DEADLINE_S')})"
                    )
    except (OSError, ValueError, http.client.HTTPException) as err:
        raise _FetchError(f"did not answer ({type(err).__name__}: {_clip(str(err))})") from None
    return bytes(body)


# ---- the screen -------------------------------------------------------------------------------------------


def render(s: dict[str, Any]) -> str:
    """The status as a few aligned lines."""
    return "\n".join(
        f"{label:<13}{text}"
        for part in (_run_lines, _training_lines, _evaluator_lines, _service_lines)
        for label, text in part(s)
    )


Lines = list[tuple[str, str]]
STATES = {"dead": "NOT running (its `cec up` is gone)", "none": "no `cec up` running"}


def _run_lines(s: dict[str, Any]) -> Lines:
    cfg, stack = s["config"], s["stack"]
    what = cfg.get("error") or f"{cfg.get('algorithm')} on {cfg.get('env')}/{cfg.get('levels')}"
    state = STATES.get(stack["state"]) or f"running (pid {stack.get('pid')}, up {_age(stack.get('up_s'))})"
    if stack.get("error"):
        state += f" ({stack['error']})"
    return [("run", f"{s['run']}  {what}  [{s['run_dir']}]"), ("stack", state)]


def _training_lines(s: dict[str, Any]) -> Lines:
    row, ckpt, total = s["progress"], s["checkpoint"], s["config"].get("total_env_steps") or 0
    ckpt_text = (
        f"{ckpt['name']}, written {_age(ckpt['age_s'])} ago ({ckpt['count']} on disk)" if ckpt else "none"
    )
    if not row:
        return [("progress", "no metrics rows yet"), ("checkpoint", ckpt_text)]
    steps, sps = int(_number(row.get("env_steps"))), _number(row.get("env_steps_per_s"))
    progress = f"update {row.get('update')}  env steps {steps:,}"
    if total:
        progress += f" / {total:,} ({100 * steps / total:.1f}%)"
    # env steps count per seed, the rate every seed's together (as the learner's progress line prints it)
    seeds = s["config"].get("num_seeds") or 1
    progress += f"  {sps:,.0f} steps/s" + (f" ({seeds} seeds)" if seeds > 1 else "")
    running = s["trainer"]["running"]
    if running and total and sps > 0 and steps < total:
        progress += f"  ETA {_age((total - steps) * seeds / sps)}"
    training = [f"return {_num(row.get('mean_return'))}", f"shaped {_num(row.get('mean_shaped_return'))}"]
    training.append(f"entropy {_num(row.get('entropy'))}")
    if "policy_lag_mean" in row:
        training.append(f"policy lag {_num(row['policy_lag_mean'])} (max {_num(row.get('policy_lag_max'))})")
    training.append(f"last row {_age(s['at'] - row['written_at'])} ago")
    lines = [("progress", progress), ("training", "  ".join(training)), ("checkpoint", ckpt_text)]
    if not running:
        lines.insert(0, ("state", _stopped(s, finished=bool(total) and steps >= total)))
    return lines


def _stopped(s: dict[str, Any], finished: bool) -> str:
    """What a run no process trains is: finished, or stopped at its newest checkpoint (and how to go on)."""
    if finished:
        return "finished"
    name = s["checkpoint"].get("name", "")
    update = name.rpartition("_")[2]
    if not update.isdigit():
        return "stopped before its first checkpoint; nothing to continue (start it again)"
    return f"interrupted at update {int(update)}; continue with: {s['trainer']['continue_with']}"


def _record(run_dir: Path) -> dict[str, Any]:
    """The evaluator's training record of the run (`<run>/eval/record.csv`, on disk, so it outlives the
    stack), summarised (`record_summary`); {} when there is none."""
    from cec.evaluation.checkpoint_results import RECORD, parse_record, record_summary

    path = run_dir / "eval" / RECORD
    if not _small_regular(path):
        return {}
    try:
        with open_user_file(path, "training record") as f:
            return record_summary(parse_record(f.read(RUN_FILE_MAX_BYTES).decode("utf-8", errors="replace")))
    except (ConfigError, OSError):
        return {}


def _evaluator_lines(s: dict[str, Any]) -> Lines:
    plane, record = s["control_plane"], s.get("record") or {}
    if record:  # the scores as the evaluator recorded them in the run, also after the stack stopped
        out: Lines = [
            ("evaluator", f"{record['checkpoints']} checkpoint(s) scored; update {record['latest_update']}:")
        ]
        played = {r["partner_group"] for r in record["latest"] if r["episodes"]}
        for r in sorted(record["latest"], key=lambda r: (r["partner_group"], r["level_set"])):
            if not r["episodes"] and r["partner_group"] in played:
                continue  # a group that plays elsewhere only (the human proxies, in their own kitchens)
            score = f"return {_num(r['return_mean'])}"
            if r["return_sem"] is not None:
                score += f" ± {_num(r['return_sem'])}"
            score += f" ({r['episodes']} episodes)"
            then = record["first"].get(f"{r['partner_group']}|{r['level_set']}")
            if then and then[0] != record["latest_update"]:
                score += f"; {_num(then[1])} at update {then[0]}"
            out.append(("", f"  {r['partner_group']:<20} {r['level_set']:<12} {score}"))
        if plane.get("run_status"):
            beat = _age(plane["heartbeat_age_s"])
            out.append(("registry", f"{plane['run_status']}, heartbeat {beat} ago ({plane['redis']})"))
        return out
    if not plane:
        return []
    if "error" in plane:
        return [("evaluator", plane["error"])]
    out = []
    if plane.get("scores"):
        out.append(("evaluator", f"{plane['scored']} checkpoint(s) scored; latest {plane['latest_scored']}:"))
        for r in sorted(plane["scores"], key=lambda r: (r["partner_group"], r["level_set"])):
            score = f"return {_num(r.get('return_mean'))} ({r.get('episodes', '?')} episodes)"
            out.append(("", f"  {r['partner_group']:<14} {r['level_set']:<12} {score}"))
    else:
        out.append(("evaluator", "no checkpoint of this run scored yet"))
    if plane.get("run_status"):
        beat = _age(plane["heartbeat_age_s"])
        out.append(("registry", f"{plane['run_status']}, heartbeat {beat} ago ({plane['redis']})"))
    return out


def _service_lines(s: dict[str, Any]) -> Lines:
    out: Lines = []
    level, learner, services = s["level_server"], s["learner"], s["stack"].get("services")
    if level:
        sent, streams = int(level.get("levels_sent", 0)), int(level.get("active_streams", 0))
        buffer = int(level.get("curriculum_buffer", 0))
        up = f"up: {sent:,} levels sent, {streams} active stream(s), curriculum buffer {buffer:,}"
        out.append(("level server", level.get("error") or up))
    if learner:
        version, restarts = int(learner.get("policy_version", 0)), int(learner.get("restarts", 0))
        up = f"up: policy version {version}, restarts {restarts}"
        out.append(("learner", learner.get("error") or up))
    if services:
        out.append(("services", ", ".join(f"{n} {'up' if up else 'DOWN'}" for n, up in services.items())))
    return out


def _num(x: Any) -> str:
    return f"{x:.3g}" if isinstance(x, int | float) and math.isfinite(x) else "-"


def _age(seconds: Any) -> str:
    if not isinstance(seconds, int | float) or not math.isfinite(seconds):
        return "?"
    s = max(0, int(seconds))
    if s < 120:
        return f"{s} s"
    if s < 7200:
        return f"{s // 60} min"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


def to_json(status: dict[str, Any]) -> str:
    """The status as strict JSON: a NaN or infinite number is null (JSON has no such numbers)."""
    return json.dumps(_finite(status), indent=1, default=str, allow_nan=False)


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


# ---- command line -----------------------------------------------------------------------------------------


def no_run(runs: str) -> str:
    """What `cec status` says when there is no run to show, and how to start one."""
    return (
        f"no run under {runs}/ yet. Start one: `make up` or `cec up` (the whole service, training the "
        "default preset), or `cec train --config configs/train/cramped_room_ci.yaml` (one process); a run "
        "elsewhere: cec status RUN_DIR"
    )


def _cmd_status(args: argparse.Namespace) -> int:
    run_dir = Path(args.run_dir) if args.run_dir else find_run(Path(args.runs))
    if args.watch is None:
        if run_dir is None:
            print(f"cec status: {no_run(args.runs.rstrip('/'))}", file=sys.stderr)
            return 1
        status = collect(run_dir, args.redis)
        print(to_json(status) if args.json else render(status), flush=True)
        return 0
    try:  # Ctrl-C stops it, whether it sleeps or reads the run
        while True:
            run_dir = run_dir or find_run(Path(args.runs))  # a run is shown once one starts
            if run_dir is None:
                text = no_run(args.runs.rstrip("/"))
            else:
                status = collect(run_dir, args.redis)
                text = to_json(status) if args.json else render(status)
            sys.stdout.write("\x1b[H\x1b[2J" + text + f"\n\n(every {args.watch:g} s; Ctrl-C stops)\n")
            sys.stdout.flush()
            time.sleep(args.watch)
    except KeyboardInterrupt:
        return 0


def add_subcommands(sub: Any) -> None:
    st = sub.add_parser(
        "status", help="one screen on a run: progress, checkpoints, evaluator scores, services"
    )
    st.add_argument("run_dir", nargs="?", help="the run directory (default: the newest run under --runs)")
    st.add_argument("--runs", default="runs", help="where to look for the newest run (default: runs/)")
    st.add_argument(
        "--watch", type=float, nargs="?", const=5.0, metavar="S", help="redraw every S seconds (default 5)"
    )
    st.add_argument("--json", action="store_true", help="print the status as JSON (for scripts)")
    st.add_argument("--redis", default="", help="control-plane URL (default: the one `cec up` recorded)")
    st.set_defaults(func=_cmd_status)
