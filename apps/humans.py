"""`cec humans ...`: the recorded human-human Overcooked games, imported, replayed, cloned into proxies.

    cec humans import [--out data/humans]          read overcooked-ai's games once, write the safe format
    cec humans replay [--data data/humans]         replay every recorded step through our dynamics
    cec humans bc [--data data/humans] [--out DIR]  behaviour-cloned human proxies -> DIR/zoo.yaml
    cec humans bc --from-play RECORDS [--out DIR]   one proxy from a study's `cec play` records

`import` is the only place the games' pickles are read: they are pandas pickles inside the trusted
`overcooked-ai` package (the `peers` extra: `pip install -e '.[peers]'`), and they are opened only after
their SHA-256 matches the one pinned here (that of `overcooked-ai` 1.1.0). Everything downstream reads the
safe format (`cec.humans.data`).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import hashlib
import json
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from apps.machine import log_line
from cec.agents.zoo import HUMAN_PROXY
from cec.config import ConfigError
from cec.envs.overcooked.state import Action
from cec.humans.bc import BCConfig
from cec.humans.data import (
    DATA_KITCHENS,
    FORMAT,
    KITCHENS,
    SPLITS,
    HumanDataError,
    Steps,
    convert_action,
    convert_state,
    load_steps,
    save_steps,
    stack_steps,
)
from cec.levels.overcooked_ai import PACKAGE, PACKAGE_VERSION, package_dir

if TYPE_CHECKING:
    from cec.humans.bc import BCResult, Samples

#: The pickles of `overcooked-ai` 1.1.0 (`overcooked_ai_py/data/human_data/`) by split, with their SHA-256.
PICKLES = {
    "train": (
        "clean_train_trials.pickle",
        "28659cfd09ee033d82b56bed905b239f078877e1b09d1f1b916e4bc0480ca4fa",
    ),
    "test": ("clean_test_trials.pickle", "59979552a053f1efe762de976f37dd83e269d70d19b67613c61e856c86705666"),
}
DEFAULT_DATA = "data/humans"


def package_data_dir() -> Path:
    """`overcooked_ai_py/data/human_data` of the installed package (found without importing it)."""
    package = package_dir()
    if package is None:
        raise ConfigError(
            f"the {PACKAGE} package (PyPI: overcooked-ai=={PACKAGE_VERSION}) is not installed; install the "
            "peers extra: pip install -e '.[peers]' (make install does)"
        )
    return package / "data" / "human_data"


def read_split(split: str, *, games_per_kitchen: int | None = None, log: TextIO = sys.stderr) -> Steps:
    """One split of the package's games as `Steps` (the pickle's SHA-256 checked before it is opened).

    `games_per_kitchen` keeps only the first games of each kitchen (tests)."""
    import pandas as pd  # the peers extra; only here

    name, pinned = PICKLES[split]
    path = package_data_dir() / name
    if not path.is_file():
        raise ConfigError(f"{path} does not exist; reinstall overcooked-ai=={PACKAGE_VERSION}")
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    if digest != pinned:
        raise ConfigError(
            f"{path} has SHA-256 {digest[:12]}..., not that of overcooked-ai {PACKAGE_VERSION}'s file "
            f"({pinned[:12]}...): refusing to unpickle it; reinstall overcooked-ai=={PACKAGE_VERSION}"
        )
    frame = pd.read_pickle(path)
    rows: list[dict[str, Any]] = []
    games = list(dict.fromkeys(zip(frame["layout_name"], frame["workerid_num"], strict=True)))
    kept: dict[str, int] = {}
    for trial, (layout, worker) in enumerate(games):
        if layout not in DATA_KITCHENS:
            raise HumanDataError(f"{path}: unknown kitchen {layout!r}; expected one of {list(DATA_KITCHENS)}")
        kitchen = DATA_KITCHENS[layout]
        kept[kitchen] = kept.get(kitchen, 0) + 1
        if games_per_kitchen is not None and kept[kitchen] > games_per_kitchen:
            continue
        game = frame[(frame["layout_name"] == layout) & (frame["workerid_num"] == worker)]
        game = game.sort_values("cur_gameloop")
        for rec in game.itertuples(index=False):
            try:
                row = _convert_row(rec, kitchen)
            except (HumanDataError, KeyError, TypeError, ValueError, SyntaxError) as err:
                raise HumanDataError(
                    f"{path}: game {layout}/{worker}, step {rec.cur_gameloop}: {err}; the pickle is not "
                    f"overcooked-ai {PACKAGE_VERSION}'s"
                ) from err
            rows.append({**row, "trial": trial, "participant": int(worker)})
        log_line(
            log,
            "humans",
            f"{split}: game {trial + 1}/{len(games)} ({layout}, worker {worker}): {len(game)} steps",
        )
    return stack_steps(rows)


def _convert_row(rec: Any, kitchen: str) -> dict[str, Any]:
    state = convert_state(ast.literal_eval(rec.state), kitchen)
    nxt = convert_state(ast.literal_eval(rec.next_state), kitchen)
    joint = ast.literal_eval(rec.joint_action)
    return {
        **state,
        **{f"next_{k}": v for k, v in nxt.items()},
        "kitchen": KITCHENS.index(kitchen),
        "time": int(rec.cur_gameloop),
        "actions": [convert_action(a) for a in joint],
        "reward": float(rec.reward),
    }


def import_games(out: str | Path, *, games_per_kitchen: int | None = None, log: TextIO = sys.stderr) -> Path:
    """Reads both splits from the package and writes them in the safe format; returns `meta.json`."""
    splits = {split: read_split(split, games_per_kitchen=games_per_kitchen, log=log) for split in SPLITS}
    source = {
        "package": f"overcooked-ai=={PACKAGE_VERSION}",
        "files": {split: {"name": name, "sha256": sha} for split, (name, sha) in PICKLES.items()},
        "games_per_kitchen": games_per_kitchen,
    }
    return save_steps(splits, out, source=source)


def _cmd_import(args: argparse.Namespace) -> int:
    meta = import_games(args.out, games_per_kitchen=args.games_per_kitchen)
    print(f"wrote {meta.parent} ({FORMAT})")
    written = json.loads(meta.read_text())["splits"]  # the counts `save_steps` recorded
    for split in SPLITS:
        print(f"{split}:")
        for kitchen, c in written[split]["counts"].items():
            games, n, soups = c["games"], c["steps"], c["deliveries"]
            print(f"  {kitchen:<18} {games:>2} games {n:>6} steps {soups:>4} deliveries")
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    from cec.humans.replay import COMPARED, replay_steps

    worst = 1.0
    for split in SPLITS:
        steps = load_steps(args.data, split)
        for kitchen, r in replay_steps(steps).items():
            worst = min(worst, r.share)
            print(f"{split:<5} {kitchen:<18} {r.exact:>6}/{r.steps:<6} exact ({100 * r.share:.2f}%)")
            for label, n in r.classes.most_common():
                rows = ", ".join(str(steps.trial[i]) + ":" + str(steps.time[i]) for i in r.examples[label])
                print(f"      differs in {label}: {n} step(s), e.g. game:step {rows}")
    print(f"compared: {', '.join(COMPARED)}; lowest share {100 * worst:.2f}%")
    return 0


# ---------------------------------------------------------------------------------------------------------
# HUMAN PROXIES
# ---------------------------------------------------------------------------------------------------------

DEFAULT_PROXIES = "runs/humans/proxies"
#: Proxies per split, as in Carroll et al. (2019): `bc` learns from the train games (early-stopped on the
#: test games), `hp` from the test games (early-stopped on the train games) -- two disjoint sets of players.
PROXY_SPLITS = {"bc": ("train", "test"), "hp": ("test", "train")}


def train_proxies(
    data: str | Path,
    out: str | Path,
    *,
    kitchens: Sequence[str] = ("all", *KITCHENS),
    config: BCConfig | None = None,
    log: TextIO = sys.stderr,
) -> Path:
    """Trains a `bc` and an `hp` proxy per kitchen (`all`: one across the five), saves each as a one-seed
    parameter checkpoint, writes `out/zoo.yaml` (algorithm `human_proxy`; per-kitchen proxies restricted
    to their kitchen) and `out/bc.json` (figures per proxy). Returns the manifest."""
    from cec.humans.bc import samples, train_bc

    config = config or BCConfig()
    unknown = sorted(set(kitchens) - {"all", *KITCHENS})
    if unknown:
        raise ConfigError(f"unknown kitchen(s) {unknown}; choose from {['all', *KITCHENS]}")
    out = Path(out)
    split_samples = {split: samples(load_steps(data, split)) for split in SPLITS}
    entries, figures = [], {}
    for kitchen in kitchens:
        for prefix, (fit_on, stop_on) in PROXY_SPLITS.items():
            name = f"{prefix}_{kitchen}"
            fit, stop = split_samples[fit_on], split_samples[stop_on]
            if kitchen != "all":
                code = KITCHENS.index(kitchen)
                fit, stop = fit.select(fit.kitchen == code), stop.select(stop.kitchen == code)
            result = train_bc(fit, stop, config, log=log, label=name)
            entries.append(_save_proxy(out, name, result, config, None if kitchen == "all" else kitchen))
            figures[name] = {
                "kitchen": kitchen,
                "trained_on": fit_on,
                "early_stopped_on": stop_on,
                **_proxy_figures(fit, stop, result),
            }
            acc, ce = result.test_accuracy, result.test_cross_entropy
            log_line(
                log, "humans", f"{name}: on the {stop_on} games accuracy {acc:.3f}, cross-entropy {ce:.3f}"
            )
    return _write_proxies(out, entries, figures, config)


def _save_proxy(
    out: Path, name: str, result: BCResult, config: BCConfig, kitchen: str | None
) -> dict[str, object]:
    """Saves a trained proxy as `out/name` (a one-seed parameter checkpoint, algorithm `human_proxy`);
    returns its zoo entry (restricted to `kitchen` when one is given)."""
    from cec import checkpoints
    from cec.agents.policy import Policy, save_policy
    from cec.envs.task import EnvConfig
    from cec.training.config import TrainConfig
    from cec.training.run import config_dict

    carrier = TrainConfig(
        algorithm="ippo",
        env=EnvConfig(levels=kitchen or KITCHENS[0]),
        network_overrides=config.network,
        seed=config.seed,
    )  # the network and game the parameters belong to
    policy = Policy(name, HUMAN_PROXY, config.seed, result.params, config.network, carrier.env)
    saved = save_policy(
        policy, out / name, config=config_dict(carrier), env_steps=0, update=result.best_epoch
    )
    entry: dict[str, object] = {
        "name": name,
        "algorithm": HUMAN_PROXY,
        "seed": config.seed,
        "checkpoint": name,
        "sha256": checkpoints.read_meta(saved)["sha256"],
    }
    if kitchen is not None:
        entry["levels"] = [kitchen]
    return entry


def _proxy_figures(fit: Samples, stop: Samples, result: BCResult) -> dict[str, object]:
    """A trained proxy's figures: sample counts, the kept epoch, its held-out accuracy and cross-entropy
    beside the frequency-only baseline's, and the per-epoch history."""
    return {
        "samples": len(fit),
        "early_stop_samples": len(stop),
        "best_epoch": result.best_epoch,
        "cross_entropy": round(result.test_cross_entropy, 4),
        "accuracy": round(result.test_accuracy, 4),
        **_frequency_baseline(fit, stop),
        "history": result.history,
    }


def _write_proxies(
    out: Path, entries: list[dict[str, object]], figures: dict[str, Any], config: BCConfig
) -> Path:
    """Adds proxies' figures to `out/bc.json` and their entries to `out/zoo.yaml` (proxies saved there
    earlier under other names stay); returns the manifest."""
    from apps.zoo_build import MANIFEST, merge_manifest

    figures_file = out / "bc.json"
    if figures_file.exists():  # proxies of other kitchens trained earlier stay
        figures = {**_read_figures(figures_file), **figures}
    doc = {"config": dataclasses.asdict(config), "proxies": figures}
    figures_file.write_text(json.dumps(doc, indent=1) + "\n")
    return merge_manifest(
        out / MANIFEST, "Written by `cec humans bc`: behaviour-cloned human proxies.", entries
    )


#: The largest `bc.json` read (a proxy's figures and per-epoch history are a few kB).
FIGURES_MAX_BYTES = 16 << 20


def _read_figures(path: Path) -> dict[str, Any]:
    """The `proxies` of a `bc.json` written earlier; `ConfigError` naming the file when it is not one (not a
    regular file, larger than `FIGURES_MAX_BYTES`, not JSON, or without a `proxies` mapping)."""
    from cec.config import read_user_json

    doc = read_user_json(path, "proxy figures file", FIGURES_MAX_BYTES, f"{__name__}.FIGURES_MAX_BYTES")
    if not isinstance(doc, dict) or not isinstance(doc.get("proxies"), dict):
        raise ConfigError(
            f"proxy figures file {str(path)!r} is not one `cec humans bc` writes (no `proxies` mapping); "
            "move it away or give another --out"
        )
    return doc["proxies"]


def play_proxy(
    records: str | Path, out: str | Path, *, config: BCConfig | None = None, log: TextIO = sys.stderr
) -> Path:
    """Clones one proxy, `play_<study>`, from a study's `cec play` records (`records`: the study's records
    folder, `<storage dir>/<study name>`): every step of every finished round (practice included) gives
    the human seat's observation and action (`services.play.human_samples`). It is fitted on the first
    half of the participants (sorted by id) and early-stopped on the others; with a single participant,
    on the first half of their rounds and early-stopped on the rest. Saved and entered in `out/zoo.yaml`
    and `out/bc.json` as `train_proxies` does. Returns the manifest."""
    from cec.humans.bc import train_bc
    from services.play.human_samples import human_samples, read_play_records

    config = config or BCConfig()
    out = Path(out)
    recs = read_play_records(records)
    participants = sorted(recs.rounds)
    name = "play_" + re.sub(r"[^A-Za-z0-9_-]", "_", recs.study)
    rounds = [r for p in participants for r in recs.rounds[p]]
    log_line(
        log,
        "humans",
        f"{recs.folder}: {len(participants)} participant(s) with {len(rounds)} finished round(s), "
        f"{recs.steps} human steps (practice included; {recs.participants_without_rounds} participant(s) "
        "without a finished round)",
    )
    if len(participants) >= 2:
        half = (len(participants) + 1) // 2
        fit_rounds = [r for p in participants[:half] for r in recs.rounds[p]]
        stop_rounds = [r for p in participants[half:] for r in recs.rounds[p]]
        split = "participants"
        trained_on, stopped_on = _count(half, "participant"), _count(len(participants) - half, "participant")
    else:
        if len(rounds) < 2:
            raise ConfigError(
                f"{recs.folder}: one participant with one finished round; a proxy needs two participants, "
                "or two finished rounds of one, to fit on one part and early-stop on the other"
            )
        half = (len(rounds) + 1) // 2
        fit_rounds, stop_rounds = rounds[:half], rounds[half:]
        split = "rounds"
        trained_on, stopped_on = _count(half, "round"), _count(len(rounds) - half, "round")
        log_line(
            log,
            "humans",
            f"a single participant ({participants[0]}): split by rounds instead of participants, fitted on "
            f"their first {half} finished round(s), early-stopped on the last {len(rounds) - half}",
        )
    fit, stop = human_samples(fit_rounds, participants), human_samples(stop_rounds, participants)
    result = train_bc(fit, stop, config, log=log, label=name)
    entry = _save_proxy(out, name, result, config, None)
    figures = {
        name: {
            "kitchen": "play",
            "source": str(recs.folder),
            "study": recs.study,
            "levels": sorted({str(r.start["level"]) for r in rounds}),
            "split": split,
            "trained_on": trained_on,
            "early_stopped_on": stopped_on,
            "fit_participants": sorted({r.participant for r in fit_rounds}),
            "early_stop_participants": sorted({r.participant for r in stop_rounds}),
            **_proxy_figures(fit, stop, result),
        }
    }
    acc, ce = result.test_accuracy, result.test_cross_entropy
    log_line(log, "humans", f"{name}: on the {stopped_on} accuracy {acc:.3f}, cross-entropy {ce:.3f}")
    return _write_proxies(out, [entry], figures, config)


def _frequency_baseline(fit: Samples, stop: Samples) -> dict[str, float]:
    """Accuracy and cross-entropy on `stop` of predicting `fit`'s action frequencies (no observation)."""
    freq = np.bincount(fit.actions, minlength=len(Action)) / len(fit)
    return {
        "frequency_accuracy": round(float(np.mean(stop.actions == freq.argmax())), 4),
        "frequency_cross_entropy": round(float(-np.mean(np.log(freq[stop.actions]))), 4),
    }


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"


def _cmd_bc(args: argparse.Namespace) -> int:
    try:
        config = BCConfig(epochs=args.epochs, seed=args.seed, **_preset_network(args.preset))
    except ConfigError as err:
        return _bc_error(str(err))
    if args.from_play is not None:
        from services.play.recording import RecordError

        if args.kitchens:
            return _bc_error("--kitchens applies to --data (the published games), not to --from-play")
        try:
            manifest = play_proxy(args.from_play, args.out, config=config)
        except (ConfigError, RecordError) as err:
            return _bc_error(str(err))
    else:
        kitchens = args.kitchens or ("all", *KITCHENS)
        manifest = train_proxies(args.data or DEFAULT_DATA, args.out, kitchens=kitchens, config=config)
    figures = _read_figures(manifest.parent / "bc.json")
    print(f"wrote {manifest}")
    print(f"{'proxy':<22} {'held-out games':<15} {'accuracy':>8} {'CE':>6}   frequency-only: accuracy, CE")
    for name, f in figures.items():
        print(f"{name:<22} {f['early_stopped_on']:<15} {f['accuracy']:>8.3f} {f['cross_entropy']:>6.3f}"
              f"   {f['frequency_accuracy']:.3f}, {f['frequency_cross_entropy']:.3f}")  # fmt: skip
    return 0


def _preset_network(preset: str | None) -> dict[str, Any]:
    """{"network": the network of a training preset, without E3T's partner model (cross-play embeds one
    for it)} ({} without a preset: the CEC CPU recipe's)."""
    if preset is None:
        return {}
    from cec.config import load_config
    from cec.training.config import TrainConfig

    network = load_config(TrainConfig, preset, []).network_config
    return {"network": dataclasses.replace(network, partner_history=0)}


def _bc_error(message: str) -> int:
    print(f"cec humans bc: error: {message}", file=sys.stderr)
    return 2


def add_subcommands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers `cec humans import|replay` on the `cec` command's subparsers."""
    humans = sub.add_parser("humans", help="recorded human-human games: import, replay, human proxies")
    humans_sub = humans.add_subparsers(dest="humans_command", required=True)
    imp = humans_sub.add_parser(
        "import", help=f"read overcooked-ai {PACKAGE_VERSION}'s human-human games once, write the safe format"
    )
    imp.add_argument("--out", default=DEFAULT_DATA, help=f"folder to write (default {DEFAULT_DATA})")
    imp.add_argument("--games-per-kitchen", type=int, help="keep only the first N games of each kitchen")
    imp.set_defaults(func=_cmd_import)
    rep = humans_sub.add_parser(
        "replay", help="replay every recorded step through our dynamics, report matches"
    )
    rep.add_argument("--data", default=DEFAULT_DATA, help=f"imported folder (default {DEFAULT_DATA})")
    rep.set_defaults(func=_cmd_replay)
    bc = humans_sub.add_parser(
        "bc",
        help="behaviour-clone human proxies (bc: train games, hp: test games; or one from cec play records)",
    )
    source = bc.add_mutually_exclusive_group()
    source.add_argument("--data", help=f"imported folder (default {DEFAULT_DATA})")
    source.add_argument(
        "--from-play",
        metavar="DIR",
        help="a study's `cec play` records folder (<storage dir>/<study name>): one proxy, play_<study>, "
        "from the human seat of every finished round",
    )
    bc.add_argument(
        "--out", default=DEFAULT_PROXIES, help=f"proxies and zoo.yaml (default {DEFAULT_PROXIES})"
    )
    bc.add_argument("--kitchens", nargs="+", help="all and/or classic kitchen names (default: all + each)")
    bc.add_argument("--epochs", type=int, default=BCConfig.epochs, help="passes over the games (best kept)")
    bc.add_argument("--seed", type=int, default=0, help="initialisation and sample order")
    bc.add_argument(
        "--preset",
        metavar="YAML",
        help="clone with this training preset's network (a proxy plays only with agents of its architecture; "
        "feed-forward only); default: the CEC CPU recipe's",
    )
    bc.set_defaults(func=_cmd_bc)
