"""A training run carried from one working session to the next in git, compact (DESIGN rule 17).

    python scripts/carry_run.py save runs/up-release       # -> carry/up-release/ (commit it, once a session)
    python scripts/carry_run.py restore carry/up-release   # -> runs/up-release/, then `cec up --resume`
    python scripts/carry_run.py save runs/reproduce/overcooked-cpu/zoo/runs/* --into carry/repro
    python scripts/carry_run.py restore carry/repro/* --run-dir runs/reproduce/overcooked-cpu/zoo/runs
    python scripts/carry_run.py save --record-only runs/reproduce/overcooked-cpu/zoo/runs/ippo_* --into ...
    python scripts/carry_run.py save-tables runs/reproduce/overcooked-cpu --out carry/repro-tables
    python scripts/carry_run.py restore-tables carry/repro-tables --work runs/reproduce/overcooked-cpu

`save` keeps the newest checkpoint's parameters, optimizer state, keys and update count (not the envs'
carries: the episodes in flight; a finished run's optimizer state neither, nothing continues from it), and
every older checkpoint the run kept (its milestones, which learning curves are played from) as parameters,
keys and count, with the run's config, metrics and the evaluator's record (compressed). For a finished
run of a reproduction, `--newest-only` keeps its last checkpoint alone, the one that plays (a run no other
starts from, with no learning curve), and `--record-only` its config, metrics and checkpoints' metadata,
no parameters, once its games are played and cached (the record is what its report needs, at a few kB);
`save-tables` carries those cached games (a reproduction's line-up tables, bzip2). `restore` writes
them back as the run's checkpoints, the carries (and an older checkpoint's optimizer state) drawn afresh
from the run's keys (`Trainer.init`), so `cec up --resume` (or `cec train --resume`) continues the run from
its newest update; the only difference from an uninterrupted run is that its envs start new episodes there.
A run that starts from another's checkpoint (`init_from`) is restored after that one. Project tooling: the
product never reads `carry/` (`scripts/history_weight.py` bounds what it may hold).
"""

from __future__ import annotations

import argparse
import gzip
import json
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
STATE = "state"  # the newest checkpoint's folder
OLDER = "checkpoints"  # the older checkpoints' folders, by their names in the run
FILES = ("config.yaml", "metrics.jsonl", "metrics.csv", "eval/record.csv", "logs/resume_command")
KEPT = ("params", "opt_state", "key", "update")  # of the newest checkpoint of a run still training
PARAMS_ONLY = ("params", "key", "update")  # of the others: what evaluating them needs
FIELDS = "carried_fields"  # in a carried checkpoint's metadata: which of the state's fields it holds
RECORD_WHY = (
    "its run was carried (scripts/carry_run.py save --record-only) as its record, without parameters, once "
    "its games were played and cached; to play new games, remove the run's checkpoints and build again"
)


def _trainer(config: dict):  # noqa: ANN202 - a Trainer of the run's config
    from cec.config import from_dict
    from cec.training.config import TrainConfig
    from cec.training.trainer import Trainer

    return Trainer(from_dict(TrainConfig, config, where="the run's config"))


def save(run: Path, out: Path, *, record_only: bool = False, newest_only: bool = False) -> Path:
    from cec import checkpoints

    saved = checkpoints.CheckpointStore(run, keep_last=1).list()
    if not saved:
        raise SystemExit(f"{run} has no checkpoint to carry")
    last = checkpoints.read_meta(saved[-1].path)
    trainer = _trainer(last["config"])
    finished = last["update"] >= trainer.config.num_updates
    if (record_only or newest_only) and not finished:
        flag = "--record-only" if record_only else "--newest-only"
        raise SystemExit(f"{run} has not finished: carry it whole (without {flag}) to train it on")
    if newest_only:  # its last checkpoint, which plays: not the milestones others start from or curves read
        saved = saved[-1:]
    template = None if record_only else trainer.state_template()  # a record loads no state
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    for i, info in enumerate(saved):
        meta = checkpoints.read_meta(info.path)
        newest = i == len(saved) - 1
        if record_only:  # its metadata as it is (the SHA-256 its cached games are keyed by), no state
            metadata = {**meta["metadata"], checkpoints.RECORD_ONLY: RECORD_WHY}
            target = out / STATE if newest else out / OLDER / info.path.name
            target.mkdir(parents=True)
            (target / checkpoints.META_FILE).write_text(json.dumps({**meta, "metadata": metadata}, indent=2))
            continue
        fields = KEPT if newest and not finished else PARAMS_ONLY
        state, _ = checkpoints.load(info.path, template)
        metadata = {**meta["metadata"], "carried_from": info.path.name, FIELDS: list(fields)}
        checkpoints.save(out / STATE if newest else out / OLDER / info.path.name,
                         {name: getattr(state, name) for name in fields}, update=meta["update"],
                         env_steps=meta["env_steps"], config=meta["config"], metadata=metadata,
                         milestone=bool(meta["milestone"]))  # fmt: skip
    for name in FILES:
        if (run / name).is_file():
            target = out / (name.replace("/", "__") + ".gz")
            target.write_bytes(gzip.compress((run / name).read_bytes(), 9))
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    print(f"carried {len(saved)} checkpoint(s) of {run}, the newest {saved[-1].path.name}, to {out} "
          f"({size / 1e6:.1f} MB)")  # fmt: skip
    return out


def restore(carried: Path, run_dir: Path) -> Path:
    import jax

    from cec import checkpoints

    newest = checkpoints.read_meta(carried / STATE)
    trainer = _trainer(newest["config"])
    # the run's shapes, with carries drawn afresh from its keys (a record has no state to fill)
    fresh = None if checkpoints.RECORD_ONLY in newest["metadata"] else trainer.init()
    run = run_dir / trainer.config.run_name
    for name in FILES:
        source = carried / (name.replace("/", "__") + ".gz")
        if source.is_file():
            (run / name).parent.mkdir(parents=True, exist_ok=True)
            (run / name).write_bytes(gzip.decompress(source.read_bytes()))
    store = checkpoints.CheckpointStore(run, keep_last=1)
    for path in [*sorted((carried / OLDER).glob("update_*")), carried / STATE]:  # oldest first
        meta = checkpoints.read_meta(path)
        metadata = dict(meta["metadata"])
        if checkpoints.RECORD_ONLY in metadata:  # a record: its metadata back, no state
            written = store.path(meta["update"])
            written.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path / checkpoints.META_FILE, written / checkpoints.META_FILE)
            continue
        if fresh is None:
            raise SystemExit(f"{path} holds a state, its run's newest checkpoint a record: carry it again")
        fields = metadata.pop(FIELDS, KEPT)  # a carry from before older checkpoints were kept: all of KEPT
        kept, _ = checkpoints.load(path, {name: getattr(fresh, name) for name in fields})
        written = checkpoints.save(store.path(meta["update"]), jax.device_get(fresh._replace(**kept)),
                                   update=meta["update"], env_steps=meta["env_steps"], config=meta["config"],
                                   metadata=metadata, milestone=bool(meta["milestone"]))  # fmt: skip
    if checkpoints.RECORD_ONLY in meta["metadata"]:
        print(f"restored {run.name}'s record to {written.parent} (finished at update {meta['update']}; "
              "its checkpoints' metadata, no parameters)")  # fmt: skip
    else:
        print(f"restored {run.name} to {written.parent} (newest: update {meta['update']}); continue with "
              "its `--resume`")  # fmt: skip
    return written


TABLE_FILES = ("results.key.json", "results.time.json")  # beside a cached table's results.csv


def save_tables(work: Path, out: Path) -> Path:
    """Every finished line-up table of a reproduction's work folder (`parts/*/` and `steps*/parts/*/` with
    their key: `apps.reproduce.pipeline.cached_table`) into `out`, `results.csv` compressed (bzip2, read as
    it is), the key and the time as they are."""
    import bz2

    from cec.evaluation.results import stored

    shutil.rmtree(out, ignore_errors=True)
    tables = sorted(k.parent for k in work.glob("**/parts/*/results.key.json"))
    for table in tables:
        target = out / table.relative_to(work)
        target.mkdir(parents=True)
        source = stored(table / "results.csv")  # as an earlier restore left it: compressed
        raw = gzip.decompress(source.read_bytes()) if source.suffix == ".gz" else source.read_bytes()
        (target / "results.csv.bz2").write_bytes(raw if source.suffix == ".bz2" else bz2.compress(raw, 9))
        for name in TABLE_FILES:
            if (table / name).is_file():
                shutil.copyfile(table / name, target / name)
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) if tables else 0
    print(f"carried {len(tables)} line-up table(s) of {work} to {out} ({size / 1e6:.1f} MB)")
    return out


def restore_tables(carried: Path, work: Path) -> None:
    """The tables of `save_tables` back into the work folder (compressed: read as they are); a table the
    work folder has under the same key is left as it is."""
    restored = 0
    for key in sorted(carried.glob("**/parts/*/results.key.json")):
        target = work / key.parent.relative_to(carried)
        if (target / key.name).is_file() and (target / key.name).read_bytes() == key.read_bytes():
            continue
        shutil.rmtree(target, ignore_errors=True)
        shutil.copytree(key.parent, target)
        restored += 1
    print(f"restored {restored} line-up table(s) into {work}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="what", required=True)
    s = sub.add_parser("save", help="runs' checkpoints, compact, each into <--into>/<run name>")
    s.add_argument("runs", type=Path, nargs="+")
    s.add_argument("--into", type=Path, default=ROOT / "carry", help="default: carry/")
    s.add_argument("--out", type=Path, default=None, help="one run's folder (default: <--into>/<run name>)")
    s.add_argument(
        "--record-only",
        action="store_true",
        help="finished runs whose games are played: config, metrics and checkpoints' metadata, no parameters",
    )
    s.add_argument(
        "--newest-only",
        action="store_true",
        help="finished runs that only play (no FCP population, no learning curve): the last checkpoint",
    )
    r = sub.add_parser("restore", help="carried runs back into the runs folder, in the order given")
    r.add_argument("carried", type=Path, nargs="+")
    r.add_argument("--run-dir", type=Path, default=ROOT / "runs")
    t = sub.add_parser("save-tables", help="a reproduction work folder's played line-up tables, compressed")
    t.add_argument("work", type=Path)
    t.add_argument("--out", type=Path, required=True)
    u = sub.add_parser("restore-tables", help="carried line-up tables back into a reproduction work folder")
    u.add_argument("carried", type=Path)
    u.add_argument("--work", type=Path, required=True)
    args = ap.parse_args(argv)
    if args.what == "save-tables":
        save_tables(args.work, args.out)
    elif args.what == "restore-tables":
        restore_tables(args.carried, args.work)
    elif args.what == "save":
        if args.out is not None and len(args.runs) > 1:
            ap.error(f"--out names one run's folder; {len(args.runs)} runs were given: use --into")
        for run in args.runs:
            save(run, args.out or args.into / run.name, record_only=args.record_only,
                 newest_only=args.newest_only)  # fmt: skip
    else:
        for carried in args.carried:
            restore(carried, args.run_dir)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
