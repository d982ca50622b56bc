"""`cec zoo build SPEC.yaml --out ZOO_DIR`: train a partner zoo from a declarative spec, write its manifest.

The spec names what to train, one entry per preset (docs/training.md):

    entries:
      - {preset: configs/train/dd_ippo_quick.yaml, seeds: [0, 1, 2], overrides: ["total_env_steps=100000"]}
      - {preset: configs/train/dd_fcp_quick.yaml, seeds: [0]}

    preset     a training preset (relative to the current directory, else to the spec's folder)
    seeds      the seeds to train (default: the preset's `seed` .. `seed + num_seeds - 1`); consecutive
               seeds are one run (`num_seeds` vmapped seeds), others one run per seed
    overrides  `key=value` overrides of the preset (not `seed`, `num_seeds`, `run_dir`, `name`)
    name       optional run-name stem (default `<algorithm>-<env>-<levels>`); runs are `<stem>-s<first seed>`
    label      optional algorithm label its policies get in the manifest (default: the preset's `algorithm`),
               e.g. `cec_nolstm` for an ablation that reports apart from the algorithm it varies

Runs go to `ZOO_DIR/runs/`, in spec order. Paths in a preset under its own `run_dir` (FCP's
`partner.population[].run`, CEC-Finetune's `init_from`, e.g. `runs/ippo-dual_destination-fixed-s0`) are
re-rooted to `ZOO_DIR/runs/`, so a population or a fine-tuning start can be an earlier entry of the spec.

Everything is checked before any training: the spec's keys, the presets and overrides (as `cec train`
would), run and policy names that two entries would share, populations and `init_from` runs that are
neither on disk nor trained by an earlier entry, and finished runs whose config no longer matches the spec.
A run that already finished is skipped, an interrupted one resumed, so running the same command again
after an interruption continues the build.

`ZOO_DIR/zoo.yaml` is a manifest in the format of `cec.agents.zoo` (one policy per run and seed, each
at its run's final checkpoint, paths relative to ZOO_DIR), extended with `env`, `layout` (the training
level distribution), `env_steps` and `sha256` (of the checkpoint's state file, from its meta.json).
Single-task Overcooked agents carry `levels: [<kitchen>]` (they meet others on their own kitchen only).

Size: one command's pipeline in the order it runs (spec -> checked plan -> build -> manifest, and the
export of its policies); the checks, which are most of it, have to see the whole spec at once.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import yaml

from cec.agents.zoo import ZOO_MAX_BYTES
from cec.config import CONFIG_MAX_BYTES, ConfigError, read_user_yaml
from cec.paths import named_path, safe_name

if TYPE_CHECKING:
    from cec.training.config import TrainConfig

ENTRY_KEYS = ("preset", "seeds", "overrides", "name", "label")
RESERVED_OVERRIDES = ("seed", "num_seeds", "run_dir", "name")
MANIFEST = "zoo.yaml"


@dataclass(frozen=True)
class PlannedRun:
    """One `train()` call of the build.

    Attributes:
        entry: index of the spec entry it comes from.
        label: `entries[i] (preset)`, for messages.
        config: the run's full config (run_dir under the zoo, seeds set, paths re-rooted).
        seeds: the seeds it trains (`config.seed` .. `config.seed + config.num_seeds - 1`).
        policy_names: the manifest name of each seed's policy.
        algorithm: the manifest's algorithm label of its policies (the entry's `label`, else the config's).
        depends_on: (what, run directory, seeds it needs or () for any) it reads when it starts (FCP
            populations, init_from).
    """

    entry: int
    label: str
    config: TrainConfig
    seeds: tuple[int, ...]
    policy_names: tuple[str, ...]
    depends_on: tuple[tuple[str, Path, tuple[int, ...]], ...]
    algorithm: str

    @property
    def run_dir(self) -> Path:
        return Path(self.config.run_dir) / self.config.run_name

    @property
    def levels(self) -> tuple[str, ...] | None:
        """The levels its policies play in cross-play: a single-task agent its own kitchen, others every
        level of the evaluation (None)."""
        env = self.config.env
        return (env.levels,) if env.game.single_task_own_level and not env.procedural else None

    @property
    def finished(self) -> bool:
        return updates_done(self) >= self.config.num_updates


@dataclass(frozen=True)
class BuildResult:
    """What `build_zoo` did: the manifest (None when interrupted, or when it did not wait for the runs
    other processes train: `left`), run names trained and skipped."""

    manifest: Path | None
    trained: tuple[str, ...]
    skipped: tuple[str, ...]
    interrupted: bool
    left: tuple[str, ...] = ()


# ---------------------------------------------------------------------------------------------------------
# SPEC -> PLAN (every check happens here, before any training)
# ---------------------------------------------------------------------------------------------------------


def load_spec(path: str | Path) -> list[dict[str, Any]]:
    """The spec's entries as plain mappings (keys and value types checked); `ConfigError` otherwise."""
    p = Path(path)
    data = read_user_yaml(p, "zoo spec", CONFIG_MAX_BYTES, "cec.config.CONFIG_MAX_BYTES")
    if not isinstance(data, Mapping) or set(data) != {"entries"}:
        got = sorted(data) if isinstance(data, Mapping) else type(data).__name__
        raise ConfigError(
            f"zoo spec {p}: expected one top-level key `entries` (a list of {{preset, seeds, overrides, "
            f"name, label}}), got {got}"
        )
    entries = data["entries"]
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"zoo spec {p}: `entries` must be a non-empty list")
    out = []
    for i, item in enumerate(entries):
        at = f"zoo spec {p}: entries[{i}]"
        if not isinstance(item, Mapping):
            raise ConfigError(f"{at} must be a mapping with keys {list(ENTRY_KEYS)}, got {item!r}")
        unknown = sorted(set(item) - set(ENTRY_KEYS))
        if unknown:
            raise ConfigError(f"{at}: unknown key(s) {unknown}; valid keys: {list(ENTRY_KEYS)}")
        if not isinstance(item.get("preset"), str) or not item["preset"]:
            raise ConfigError(f"{at}: `preset` (a configs/train/*.yaml file) is required")
        at = f"{at} ({item['preset']})"
        seeds = item.get("seeds")
        if seeds is not None and (
            not isinstance(seeds, list)
            or not seeds
            or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds)
            or len(set(seeds)) != len(seeds)
        ):
            raise ConfigError(
                f"{at}: `seeds` must be a non-empty list of distinct integers >= 0, got {seeds!r}"
            )
        overrides = item.get("overrides", [])
        if not isinstance(overrides, list) or not all(isinstance(o, str) for o in overrides):
            raise ConfigError(f'{at}: `overrides` must be a list of "key=value" strings, got {overrides!r}')
        for o in overrides:
            key = o.partition("=")[0].strip()
            if key in RESERVED_OVERRIDES:
                fix = "the entry's `seeds`" if key in ("seed", "num_seeds") else "the entry's `name`"
                if key == "run_dir":
                    fix = "--out (runs go to ZOO_DIR/runs)"
                raise ConfigError(f"{at}: override {o!r} is set by the zoo; use {fix} instead")
        if item.get("name") is not None:  # a run folder's name stem: one plain path component
            safe_name(
                item["name"], f"{at}: `name`", fix="give the entry a plain name (letters, digits, '_', '-')"
            )
        label = item.get("label")
        if label is not None and (not isinstance(label, str) or not label):
            raise ConfigError(f"{at}: `label` must be a non-empty string, got {label!r}")
        out.append(dict(item))
    return out


def _find_preset(preset: str, spec_dir: Path) -> Path:
    for candidate in (Path(preset), spec_dir / preset):  # an absolute preset makes both the same
        if candidate.is_file():
            return candidate
    raise ConfigError(f"preset file {preset!r} does not exist (looked in . and {spec_dir})")


def _seed_groups(seeds: list[int]) -> list[tuple[int, ...]]:
    """Consecutive seeds train as one run; any other set as one run per seed."""
    ordered = sorted(seeds)
    if ordered == list(range(ordered[0], ordered[0] + len(ordered))):
        return [tuple(ordered)]
    return [(s,) for s in ordered]


def _reroot(path: str, old_root: str, new_root: Path) -> str:
    """`path` moved from under `old_root` to under `new_root` (absolute); other paths made absolute."""
    p = Path(path)
    try:
        return str(new_root / p.relative_to(old_root))
    except ValueError:
        return str(p.resolve())


def plan_zoo(spec_path: str | Path, out_dir: str | Path) -> list[PlannedRun]:
    """Checks the spec and returns the runs to train, in order. Raises `ConfigError` naming the entry."""
    from cec import checkpoints
    from cec.config import load_config
    from cec.training.config import TrainConfig

    spec_path = Path(spec_path)
    runs_root = Path(out_dir).resolve() / "runs"
    plan: list[PlannedRun] = []
    for i, item in enumerate(load_spec(spec_path)):
        label = f"entries[{i}] ({item['preset']})"
        at = f"zoo spec {spec_path}: {label}"
        try:
            preset = _find_preset(item["preset"], spec_path.parent)
            base = load_config(TrainConfig, preset, item.get("overrides", []))
        except ConfigError as err:
            raise ConfigError(f"{at}: {err}") from err
        seeds = item.get("seeds") or list(range(base.seed, base.seed + base.num_seeds))
        population = tuple(
            dataclasses.replace(e, run=_reroot(e.run, base.run_dir, runs_root))
            for e in base.partner.population
        )
        init_from = _reroot(base.init_from, base.run_dir, runs_root) if base.init_from else ""
        deps = tuple(("partner.population run", Path(e.run), e.seeds) for e in population)
        if init_from:
            deps += (
                ("init_from", Path(init_from), () if base.init_from_seed < 0 else (base.init_from_seed,)),
            )
        stem = item.get("name") or f"{base.algorithm}-{base.env.name}-{base.env.levels_label}"
        for group in _seed_groups(seeds):
            try:
                config = dataclasses.replace(
                    base,
                    seed=group[0],
                    num_seeds=len(group),
                    run_dir=str(runs_root),
                    name=f"{item['name']}-s{group[0]}" if item.get("name") else "",
                    partner=dataclasses.replace(base.partner, population=population),
                    init_from=init_from,
                )
            except ConfigError as err:
                raise ConfigError(f"{at}: {err}") from err
            names = tuple(f"{stem}-s{s}" for s in group)
            algorithm = item.get("label") or config.algorithm
            plan.append(PlannedRun(i, label, config, group, names, deps, algorithm))
    _check_plan(plan, spec_path)
    from cec.training.run import trains_as

    for run in plan:  # a finished run whose config differs from the spec: stop before any training
        latest = checkpoints.CheckpointStore(run.run_dir, keep_last=1).latest()
        if latest is not None and not trains_as(checkpoints.read_meta(latest.path)["config"], run.config):
            raise ConfigError(
                f"zoo spec {spec_path}: {run.label}: {run.run_dir} was trained with another config (the spec "
                "or the preset changed since); delete that run directory to retrain it, restore the spec, "
                "or give the entry a `name`"
            )
    return plan


def _check_plan(plan: list[PlannedRun], spec_path: Path) -> None:
    where = f"zoo spec {spec_path}"
    producers: dict[Path, int] = {}
    policies: dict[str, PlannedRun] = {}
    for run in plan:
        if run.run_dir in producers:
            raise ConfigError(
                f"{where}: {plan[producers[run.run_dir]].label} and {run.label} both train run "
                f"{run.config.run_name}; give one of them a `name`"
            )
        producers[run.run_dir] = len(producers)
        for name in run.policy_names:
            if name in policies and policies[name].entry != run.entry:
                raise ConfigError(
                    f"{where}: {policies[name].label} and {run.label} both produce policy {name}; give one "
                    "of them a `name`"
                )
            policies[name] = run
    for k, run in enumerate(plan):
        for what, dep, seeds in run.depends_on:
            source = plan[producers[dep]] if dep in producers else None
            if source is not None and producers[dep] > k:
                raise ConfigError(
                    f"{where}: {run.label} reads {dep.name}, which {source.label} trains later; move that "
                    "entry before it"
                )
            if source is not None and not set(seeds) <= set(source.seeds):
                raise ConfigError(
                    f"{where}: {run.label}: {what} {dep.name} needs seeds {sorted(seeds)}, but "
                    f"{source.label} trains seeds {list(source.seeds)} there; fix either entry's seeds"
                )
            if source is None and not dep.exists():
                raise ConfigError(
                    f"{where}: {run.label}: {what} {dep} neither exists nor is trained by an earlier entry; "
                    "add the entry that trains it (before this one) or point the preset at an existing run"
                )


# ---------------------------------------------------------------------------------------------------------
# BUILD
# ---------------------------------------------------------------------------------------------------------


def build_zoo(
    spec_path: str | Path,
    out_dir: str | Path,
    *,
    progress: bool = True,
    log: TextIO = sys.stderr,
    poll_s: float = 30.0,
    wait: bool = True,
    between: Callable[[list[PlannedRun]], object] | None = None,
) -> BuildResult:
    """Trains every run of the spec that has not finished (resuming interrupted ones), in spec order,
    then writes `out_dir/zoo.yaml`. Stops early (no manifest) when a run is interrupted (SIGINT/SIGTERM).

    Several processes may build the same zoo at once (one per core, or per machine on a shared disk): a
    run another process trains (it holds the run's lock) is passed over, as is a run whose population or
    `init_from` run is not finished yet, and both are come back to; with nothing left to start, the
    process waits (`poll_s`) for the others, or, with `wait=False`, returns without a manifest, naming the
    runs left to them (a process with other zoos to build goes on with those). Each process writes the
    manifest once every run is done. `between(plan)`, where given, runs after each run this process trains
    and before each wait: work that needs only the runs finished so far (a reproduction playing the games
    of the agents that are ready)."""
    from cec import checkpoints
    from cec.training.run import train

    plan = plan_zoo(spec_path, out_dir)
    trained: list[str] = []
    skipped: list[str] = []
    said: set[tuple[int, str]] = set()

    def say(k: int, msg: str) -> None:
        if (k, msg) not in said:
            said.add((k, msg))
            print(f"[{k + 1}/{len(plan)}] {plan[k].config.run_name} {msg}", file=log, flush=True)

    pending = list(range(len(plan)))
    while pending:
        deferred = []
        for k in pending:
            run, cfg = plan[k], plan[k].config
            if run.finished:
                say(k, "finished, skipping")
                skipped.append(cfg.run_name)
                continue
            blocker = next((p for p in plan if _reads(run, p) and not p.finished), None)
            if blocker is not None:
                say(k, f"waits for {blocker.config.run_name} (not finished)")
                deferred.append(k)
                continue
            try:  # announced only when this process can take it (a waiting process said it resumed)
                checkpoints.RunLock(run.run_dir).acquire().release()
            except checkpoints.RunBusyError as err:
                say(k, f"is trained elsewhere ({err}); going on with the others")
                deferred.append(k)
                continue
            latest = checkpoints.CheckpointStore(run.run_dir, keep_last=1).latest()
            what = f"training {cfg.num_updates} updates"
            if latest is not None:
                what = f"resuming at update {latest.update}/{cfg.num_updates}"
            say(k, f"({run.label}, {cfg.algorithm}, seeds {_seeds(run.seeds)}): {what}")
            try:
                result = train(cfg, resume=latest is not None, progress=progress, log=log)
            except checkpoints.RunBusyError as err:
                say(k, f"is trained elsewhere ({err}); going on with the others")
                deferred.append(k)
                continue
            trained.append(cfg.run_name)
            if result.interrupted:
                print(
                    f"zoo build interrupted in {cfg.run_name}; run the same command again to continue",
                    file=log,
                    flush=True,
                )
                return BuildResult(None, tuple(trained), tuple(skipped), True)
            if between is not None:
                between(plan)
        if deferred and deferred == pending:  # nothing startable: the others are training what is left
            if between is not None:
                between(plan)
            if not wait:
                left = tuple(plan[k].config.run_name for k in deferred)
                return BuildResult(None, tuple(trained), tuple(skipped), False, left)
            time.sleep(poll_s)
        pending = deferred
    manifest = write_manifest(plan, out_dir)
    print(f"wrote {manifest} ({sum(len(r.seeds) for r in plan)} policies)", file=log, flush=True)
    return BuildResult(manifest, tuple(trained), tuple(skipped), False)


def updates_done(run: PlannedRun) -> int:
    """The updates `run` has checkpointed (0 before its first checkpoint, at most `num_updates`)."""
    from cec import checkpoints

    latest = checkpoints.CheckpointStore(run.run_dir, keep_last=1).latest()
    return 0 if latest is None else min(latest.update, run.config.num_updates)


def done_fraction(runs: Sequence[PlannedRun]) -> float:
    """The share of `runs`' seed-updates checkpointed so far (1.0 when every run is finished)."""
    total = sum(r.config.num_updates * len(r.seeds) for r in runs)
    return sum(updates_done(r) * len(r.seeds) for r in runs) / total if total else 1.0


def _reads(run: PlannedRun, other: PlannedRun) -> bool:
    """Whether `run` starts from `other`'s checkpoints (an FCP population, an `init_from`)."""
    return any(dep == other.run_dir for _, dep, _ in run.depends_on)


def _seeds(seeds: tuple[int, ...]) -> str:
    return f"{seeds[0]}-{seeds[-1]}" if len(seeds) > 1 else str(seeds[0])


def manifest_entries(plan: list[PlannedRun], out_dir: str | Path) -> list[dict[str, object]]:
    """One manifest entry per (run, seed) at the run's final checkpoint (paths relative to `out_dir`)."""
    from cec import checkpoints

    root = Path(out_dir).resolve()
    entries = []
    for run in plan:
        cfg = run.config
        final = checkpoints.CheckpointStore(run.run_dir, keep_last=1).latest()
        if final is None or final.update < cfg.num_updates:
            raise checkpoints.CheckpointError(f"{run.run_dir} has not finished; run `cec zoo build` again")
        meta = checkpoints.read_meta(final.path)
        for seed, name in zip(run.seeds, run.policy_names, strict=True):
            entry: dict[str, object] = {
                "name": name,
                "algorithm": run.algorithm,
                "seed": seed,
                "checkpoint": str(final.path.relative_to(root)),
                "env": cfg.env.name,
                "layout": cfg.env.levels,
                "env_steps": int(meta["env_steps"]),
                "sha256": meta["sha256"],
            }
            if run.levels is not None:
                entry["levels"] = list(run.levels)  # a single-task agent meets others on its own kitchen
            entries.append(entry)
    return entries


def write_manifest(plan: list[PlannedRun], out_dir: str | Path) -> Path:
    """Writes `out_dir/zoo.yaml` (atomically) and returns its path."""
    path = Path(out_dir) / MANIFEST
    header = "Written by `cec zoo build`: one policy per (run, seed) at the run's final checkpoint."
    return _write_manifest(path, header, manifest_entries(plan, out_dir))


def merge_manifest(path: Path, header: str, policies: list[dict[str, object]]) -> Path:
    """Adds `policies` to the manifest at `path` (replacing entries of the same names; others are kept, and
    so is the comment at the top of the file, which says what its policies are)."""
    names = {p["name"] for p in policies}
    old = []
    if path.exists():  # the manifest a crashed build left (bounded; refused with the file named if damaged)
        data = read_user_yaml(path, "zoo manifest", ZOO_MAX_BYTES, "cec.agents.zoo.ZOO_MAX_BYTES")
        if not (isinstance(data, Mapping) and isinstance(data.get("policies"), list)):
            raise ConfigError(f"zoo manifest {str(path)!r} has no `policies` list; remove it to rebuild it")
        old = [dict(e) for e in data["policies"] if isinstance(e, Mapping) and "name" in e]
        comment = list(itertools.takewhile(lambda line: line.startswith("#"), path.read_text().splitlines()))
        header = "\n".join(line[1:].strip() for line in comment) or header
    return _write_manifest(path, header, [e for e in old if e["name"] not in names] + policies)


def _write_manifest(path: Path, header: str, policies: list[dict[str, object]]) -> Path:
    """Writes a zoo manifest atomically (a reader never sees half of it), `header` as its comment."""
    tmp = path.with_name(path.name + ".tmp")
    comment = "".join(f"# {line}\n".replace("# \n", "#\n") for line in header.splitlines())
    tmp.write_text(comment + yaml.safe_dump({"policies": policies}, sort_keys=False))
    tmp.replace(path)
    return path


def export_zoo(
    manifest: str | Path,
    out_dir: str | Path,
    *,
    names: Sequence[str] = (),
    prefix: str = "",
    results: Sequence[str | Path] = (),
) -> Path:
    """`cec zoo export`: copies a zoo's policies (all, or those named) as one-seed parameter checkpoints
    (`cec.agents.policy.save_policy`: no optimiser state, a few MB each) into `out_dir`, with a manifest
    `out_dir/zoo.yaml` (paths relative to it, SHA-256 pinned), a card and an index (`apps.zoo_bundle`:
    `card.md`, `bundle.json`), so that the folder is a bundle that loads from disk or from a URL. Entries
    already in `out_dir/zoo.yaml` under other names are kept, so a folder can collect policies from several
    zoos. `prefix` is put before each exported policy's name; `results` (`cec eval` tables of the zoo) give
    the card its evaluation. Nothing is written when an entry cannot be loaded or a table plays none of
    them."""
    from apps.zoo_bundle import evaluation, write_bundle
    from cec import checkpoints
    from cec.agents.policy import load_policy, resolve_checkpoint, save_policy
    from cec.agents.zoo import load_zoo

    entries = load_zoo(manifest)
    unknown = sorted(set(names) - {e.name for e in entries})
    if unknown:
        raise ConfigError(f"{manifest}: no entries named {unknown}; its entries: {[e.name for e in entries]}")
    chosen = [e for e in entries if e.scripted is None and (not names or e.name in names)]
    if not chosen:
        raise ConfigError(f"{manifest}: no checkpoint entries to export")
    if prefix:
        safe_name(prefix, "--prefix", fix="give a plain prefix (letters, digits, '_', '-')")
    fix = "rename the entry in the manifest (or export the others with --name)"
    for e in chosen:  # each becomes a folder of out_dir: checked before anything is loaded or written
        if safe_name(prefix + e.name, f"{manifest}: exported policy name", fix=fix) == MANIFEST:
            raise ConfigError(
                f"{manifest}: an exported policy cannot be named {MANIFEST} (the manifest); {fix}"
            )
    loaded = [(load_policy(e), checkpoints.read_meta(resolve_checkpoint(e.checkpoint))) for e in chosen]
    evaluated = evaluation(results, {prefix + e.name: e.name for e in chosen}) if results else None
    out = Path(out_dir)
    written = []
    for policy, meta in loaded:
        name = prefix + policy.name
        path = named_path(out, name, "exported policy name")
        saved = save_policy(
            policy,
            path,
            config=meta["config"],
            env_steps=meta["env_steps"],
            update=meta["update"],
            code_version=str(meta.get("metadata", {}).get("code_version", "")),
        )
        env = meta["config"].get("env", {})
        written.append(
            {
                "name": name,
                "algorithm": policy.algorithm,
                "seed": policy.seed,
                "checkpoint": name,
                "env": policy.env.name,
                "layout": env.get("levels", ""),
                "env_steps": int(meta["env_steps"]),
                "sha256": checkpoints.read_meta(saved)["sha256"],
                **({"levels": list(policy.levels)} if policy.levels else {}),
            }
        )
    header = "Written by `cec zoo export`: one-seed parameter checkpoints (cec.agents.policy.save_policy)."
    path = merge_manifest(out / MANIFEST, header, written)
    write_bundle(out, str(manifest), evaluated)
    return path


# ---------------------------------------------------------------------------------------------------------
# CLI: cec zoo build, cec zoo export
# ---------------------------------------------------------------------------------------------------------


def _cmd_zoo_build(args: argparse.Namespace) -> int:
    result = build_zoo(args.spec, args.out, progress=not args.quiet)
    if result.interrupted:
        return 130
    print(
        f"zoo: {len(result.trained)} run(s) trained, {len(result.skipped)} already finished; "
        f"manifest {result.manifest}"
    )
    return 0


def add_subcommands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers `cec zoo build` on the `cec` command's subparsers."""
    zoo = sub.add_parser("zoo", help="build a partner zoo (train from a spec, write its manifest)")
    zoo_sub = zoo.add_subparsers(dest="zoo_command", required=True)
    build = zoo_sub.add_parser(
        "build", help="train the spec's entries (skipping finished runs) and write ZOO_DIR/zoo.yaml"
    )
    build.add_argument("spec", help="zoo spec YAML: entries: [{preset, seeds, overrides, name}]")
    build.add_argument("--out", required=True, metavar="ZOO_DIR", help="runs go to ZOO_DIR/runs/")
    build.add_argument("--quiet", action="store_true", help="no per-update progress lines")
    build.set_defaults(func=_cmd_zoo_build)
    export = zoo_sub.add_parser(
        "export",
        help="copy a zoo's policies as one-seed parameter checkpoints (a few MB) into a folder: a bundle "
        "with its manifest, card and checksums that `--zoo` loads from the folder or a URL serving it",
    )
    export.add_argument("manifest", help="zoo manifest (e.g. ZOO_DIR/zoo.yaml)")
    export.add_argument("--out", required=True, metavar="DIR", help="folder for the checkpoints and zoo.yaml")
    export.add_argument("--name", action="append", default=[], help="export only this entry (repeatable)")
    export.add_argument("--prefix", default="", help="put this before each exported policy's name")
    export.add_argument(
        "--results",
        action="append",
        default=[],
        metavar="CSV",
        help="a `cec eval` table of the zoo (repeatable): the card's evaluation of each exported policy",
    )
    export.set_defaults(func=_cmd_zoo_export)


def _cmd_zoo_export(args: argparse.Namespace) -> int:
    path = export_zoo(args.manifest, args.out, names=args.name, prefix=args.prefix, results=args.results)
    print(f"exported to {path}")
    return 0
