"""`cec partners best [--ship]`: which shipped partner `cec play serve --partner best` plays in each kitchen,
chosen on validation, with the test figure beside each choice (`cec/shipped/best.yaml`).

    cec humans import && cec humans bc --kitchens cramped_room asymm_advantages coord_ring forced_coord \\
        counter_circuit                            # the validation proxies: runs/humans/proxies/zoo.yaml
    cec partners best --out DIR --ship             # DIR/best.md, and best.yaml into cec/shipped/

Per classic kitchen the candidates are the kitchen's fine-tuned agents (`ft758m-<kitchen>`, `cec_finetune`:
from the CEC seeds; `ftteach-<kitchen>`, `cec_finetune_teacher`: from the kickstarted seeds; shipped by
`cec partners finetune`) and each group of generalist seeds (the CEC seeds, `cec`; the kickstarted seeds,
`cec_teacher`); the one that cooks most on average with the kitchen's validation proxy (`bc_<kitchen>`:
cloned from the train games' people, `--proxies`) is chosen, and its figure with the test proxy
(`hp_<kitchen>`, the test games' people, shipped) reports. One cross-play per kitchen and proxy (400-step
episodes, 4 per seat order, sampled actions, the evaluation's common random numbers) into
`OUT/<kitchen>_<bc|hp>.csv.bz2`, kept (a second call reads it). Every other kitchen (the generated ones, one
a person draws) gets the generalist group with the higher cross-play on the generated validation kitchens
(`--validation`, the 100 of them): each group's seeds with each other, one episode per pairing and kitchen,
played into `OUT/validation_<group>.csv.bz2`, or read from a table given with `--validation-table
GROUP=CSV` (a release's table of the group on those kitchens). Writes `OUT/best.md` and `OUT/best.yaml`;
`--ship` puts best.yaml beside the shipped zoo (`cec/shipped/best.yaml`, what `--partner best` reads). A
choice without its validation figures (a proxy or a candidate skipped, `cec.evaluation.choice`) stops the
command, exit 2, with nothing written or shipped.
"""

from __future__ import annotations

import argparse
import functools
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml

from apps.partners.tables import (
    BC,
    EPISODES,
    PROXY,
    STEPS,
    Tables,
    check_play_sizes,
    validation_proxy,
    write_atomic,
)
from cec.agents.zoo import OTHER_KITCHENS, SHIPPED_ZOO, SkippedEntry, ZooEntry, load_zoo
from cec.config import ConfigError
from cec.evaluation.choice import choose
from cec.evaluation.markdown import pm
from cec.evaluation.results import EpisodeTable, read_csv
from cec.evaluation.seeds import seed_matrix
from cec.evaluation.stats import sem
from cec.humans.data import KITCHENS

#: The generalist groups (algorithm labels of the shipped zoo), the incumbent first (it wins a tie).
GENERALISTS = ("cec", "cec_teacher")
#: The fine-tuned agents by algorithm label, with the prefix of their shipped names (`<prefix>-<kitchen>`).
FINETUNED = {"cec_finetune": "ft758m", "cec_finetune_teacher": "ftteach"}
#: The comment of `cec/shipped/best.yaml`.
HEADER = """\
# `cec play serve --partner best`: per classic kitchen, the shipped partner that cooked most with the
# validation proxy there (bc_<kitchen>: people of the train games; the hp_ proxies report); in every other
# kitchen the generalist seeds with the higher validation cross-play. Written by
# `cec partners best --ship` (the best.md it writes beside its tables has the figures).
"""


def zoo(kitchen: str, shipped: list[ZooEntry], bc: ZooEntry) -> list[ZooEntry]:
    """The kitchen's candidates (the generalist groups' seeds, its fine-tuned agents) and both its proxies."""
    wanted = {f"hp_{kitchen}", *(f"{prefix}-{kitchen}" for prefix in FINETUNED.values())}
    return [*(e for e in shipped if e.algorithm in GENERALISTS or e.name in wanted), bc]


def with_proxy(table: EpisodeTable, proxy_algorithm: str) -> tuple[dict[str, np.ndarray], list[SkippedEntry]]:
    """Per candidate (a generalist group, or a fine-tuned agent by its algorithm label), each of its seeds'
    mean return with the proxy (NaN where the proxy is missing: `choose` refuses it); and the entries of
    the candidates or the proxy that the evaluation skipped."""
    m = seed_matrix(table)
    proxy = m.indices(proxy_algorithm)
    candidates = [a for a in (*GENERALISTS, *FINETUNED) if m.indices(a)]
    used = {*GENERALISTS, *FINETUNED, proxy_algorithm}
    skipped = [s for s in table.skipped if s.algorithm in used]
    return {a: m.partner_means(m.indices(a), proxy) for a in candidates}, skipped


def validation_crossplay(
    tables: Tables, given: dict[str, Path], spec: str, steps: int, shipped: list[ZooEntry], zoo_path: Path
) -> dict[str, tuple[float, int]]:
    """Each generalist group's (cross-play, kitchens) on the generated kitchens of `spec`: from its table in
    `given`, else played (`tables`)."""
    from cec.evaluation.parts import part_scores
    from cec.levels.named import resolve_levels

    levels = resolve_levels(spec)
    out = {}
    for group in GENERALISTS:
        seeds = [e for e in shipped if e.algorithm == group]
        if group in given:
            table, source = read_csv(given[group]), str(given[group])
        elif not seeds:
            raise ConfigError(f"{zoo_path} has no policy labelled {group!r}: ship its seeds or give --zoo")
        else:
            table = tables.get(
                f"validation_{group}", functools.partial(list, seeds), spec, episodes=1, steps=steps
            )
            source = str(tables.path(f"validation_{group}"))
        part = part_scores(table, group, levels).get("generated")
        if part is None:
            raise ConfigError(
                f"{source} has no cross-play of {group!r} on a generated kitchen of --validation {spec!r}: "
                "give the table of the group's seeds on those kitchens (cec eval --levels generated)"
            )
        out[group] = (part.xp, part.levels)
    return out


def choose_best(args: argparse.Namespace, say: Callable[[str], None]) -> dict[str, str]:
    """The choice per kitchen (played or read), then every other kitchen's; then best.md and best.yaml in
    `--out`, then `--ship`. Returns the choice."""
    out, zoo_path, proxies = Path(args.out), Path(args.zoo), Path(args.proxies).resolve()
    given = _given_tables(args.validation_table)
    shipped = load_zoo(zoo_path)
    tables = Tables(out, say)
    best: dict[str, str] = {}
    rows = []
    for kitchen in KITCHENS:
        scores, skipped = {}, {}
        for proxy, algorithm in (("bc", BC), ("hp", PROXY)):

            def entries(kitchen: str = kitchen) -> list[ZooEntry]:
                return zoo(kitchen, shipped, validation_proxy(proxies, kitchen))

            table = tables.get(
                f"{kitchen}_{proxy}",
                entries,
                kitchen,
                episodes=args.episodes,
                steps=args.max_steps,
                pairs=f"with:{proxy}_{kitchen}",
            )
            scores[proxy], skipped[proxy] = with_proxy(table, algorithm)
        chosen = choose(  # on validation: with the bc proxy (the hp figures report)
            scores["bc"], what=f"{kitchen}: the partner of `--partner best`", skipped=skipped["bc"]
        )
        best[kitchen] = f"{FINETUNED[chosen]}-{kitchen}" if chosen in FINETUNED else chosen
        rows.append((kitchen, best[kitchen], chosen, scores))
        say(f"{kitchen}: `--partner best` plays {best[kitchen]}")
    xp = validation_crossplay(tables, given, args.validation, args.max_steps, shipped, zoo_path)
    best[OTHER_KITCHENS] = choose(
        {a: [v] for a, (v, _) in xp.items()}, what="every other kitchen: the generalists of `--partner best`"
    )
    source = (
        "their release tables"
        if set(given) >= set(GENERALISTS)
        else f"one episode per pairing and kitchen, {args.validation}"
    )
    text = HEADER + yaml.safe_dump(best, sort_keys=False)
    write_atomic(out / "best.yaml", text)
    write_atomic(out / "best.md", markdown(rows, xp, best[OTHER_KITCHENS], args, source))
    say(f"report: {out / 'best.md'}")
    if args.ship:
        ship(best, text, zoo_path, shipped, say)
    else:
        say(f"to ship: the same command with --ship (writes {zoo_path.parent / 'best.yaml'})")
    return best


def ship(
    best: dict[str, str], text: str, zoo_path: Path, shipped: list[ZooEntry], say: Callable[[str], None]
) -> None:
    """best.yaml beside the shipped zoo, once every partner it names is one of the zoo's names or labels."""
    known = {e.name for e in shipped} | {str(e.algorithm) for e in shipped}
    missing = sorted(set(best.values()) - known)
    if missing:
        raise ConfigError(
            f"not shipped: {zoo_path} has no policy named or labelled {missing}; ship them first "
            "(cec partners finetune --ship) or give --zoo the zoo they are in"
        )
    write_atomic(zoo_path.parent / "best.yaml", text)
    say(f"shipped {zoo_path.parent / 'best.yaml'}")


def markdown(
    rows: list, xp: dict[str, tuple[float, int]], other: str, args: argparse.Namespace, source: str
) -> str:
    names = {
        "cec": "the CEC seeds (`cec`, 758M)",
        "cec_teacher": "the kickstarted seeds (`cec_teacher`, 21M)",
        "cec_finetune": "the kitchen's agent fine-tuned from the CEC seeds (`ft758m-<kitchen>`)",
        "cec_finetune_teacher": "... from the kickstarted seeds (`ftteach-<kitchen>`)",
    }
    out = [
        "# `cec play serve --partner best`: the partner of each kitchen",
        "",
        "Written by `cec partners best` (`--help` has the steps). Team return per "
        f"{args.max_steps} steps with the kitchen's",
        "proxy, mean over the candidate's seeds ± SE "
        f"({args.episodes} episodes per seat order); the validation proxy",
        "(`bc_<kitchen>`, people of the train games) chooses, the test proxy (`hp_<kitchen>`) reports.",
        "The bc proxies are not shipped: `cec humans bc` clones them again, and a clone made on another",
        "machine plays differently (the fine-tuned agents' bc figures here are not those of",
        "finetune/README.md), so every candidate is played with the same clone in one run.",
        "",
        "| candidate | " + " | ".join(f"{k}: bc (validation) / hp (test)" for k, _, _, _ in rows) + " |",
        "|---|" + "---|" * len(rows),
    ]
    for a, label in names.items():
        if not all(a in s["bc"] for _, _, _, s in rows):
            continue  # not shipped for every kitchen
        cells = []
        for _, _, _, s in rows:
            bc, hp = s["bc"][a], s["hp"][a]
            cells.append(f"{pm(float(np.mean(bc)), float(sem(bc)) if bc.size > 1 else None)} / "
                         f"{pm(float(np.mean(hp)), float(sem(hp)) if hp.size > 1 else None)}")  # fmt: skip
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    out.append("| **chosen** | " + " | ".join(f"**{b}**" for _, b, _, _ in rows) + " |")

    def test_mean(alone: str | None) -> float:  # over the kitchens, the hp figure of `alone` or the pick
        return float(np.mean([np.mean(s["hp"][alone or c]) for _, _, c, s in rows]))

    chosen = test_mean(None)
    alone = ", ".join(f"`{a}` alone {test_mean(a):.1f}" for a in GENERALISTS)
    kitchens = ", ".join(sorted({str(n) for _, n in xp.values()}))
    figures = ", ".join(f"`{a}` {v:.1f}" for a, (v, _) in xp.items())
    out += [
        "",
        f"With the test proxies, what `--partner best` plays scores {chosen:.1f} per {args.max_steps} steps "
        f"over the five kitchens ({alone}).",
        "",
        f"Every other kitchen: the generalists with the higher cross-play on the {kitchens} generated "
        "validation",
        f"kitchens ({source}): {figures}; chosen: **{other}**.",
        "",
    ]
    return "\n".join(out)


def _given_tables(specs: list[str]) -> dict[str, Path]:
    given = {}
    for spec in specs:
        group, sep, path = spec.partition("=")
        if not sep or group not in GENERALISTS:
            raise ConfigError(
                f"--validation-table {spec!r}: give GROUP=CSV with GROUP one of {', '.join(GENERALISTS)}"
            )
        if not Path(path).is_file():
            raise ConfigError(f"--validation-table {spec!r}: {path!r} is not a file (a cec eval table)")
        given[group] = Path(path)
    return given


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "best",
        help="the partner `cec play serve --partner best` plays per kitchen (chosen with validation proxies)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--out",
        default="runs/partners/best",
        help="the tables (a second call reads them; delete one to play it again), best.md and best.yaml",
    )
    p.add_argument(
        "--proxies", default="runs/humans/proxies/zoo.yaml", help="`cec humans bc`'s zoo: the bc_ proxies"
    )
    p.add_argument("--zoo", default=str(SHIPPED_ZOO), help="the shipped zoo: the candidates, hp_ proxies")
    p.add_argument("--episodes", type=int, default=EPISODES, help="per seat order, with each proxy")
    p.add_argument("--max-steps", type=int, default=STEPS, help=f"episode length (default {STEPS})")
    p.add_argument(
        "--validation",
        default="generated",
        help="the validation kitchens every other kitchen's choice is made on (default: generated, the 100)",
    )
    p.add_argument(
        "--validation-table",
        action="append",
        default=[],
        metavar="GROUP=CSV",
        help="read a generalist group's cross-play on --validation from this table instead of playing it",
    )
    p.add_argument("--ship", action="store_true", help="write best.yaml beside --zoo (cec/shipped/best.yaml)")
    p.set_defaults(func=_cmd_best)


def _cmd_best(args: argparse.Namespace) -> int:
    from cec.levels.named import resolve_levels

    check_play_sizes(args.episodes, args.max_steps)
    resolve_levels(args.validation)  # refused by name before anything is played
    choose_best(args, say=lambda m: print(m, file=sys.stderr, flush=True))
    return 0
