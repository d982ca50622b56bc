#!/usr/bin/env bash
# The shipped CEC seeds (cec/shipped/zoo.yaml) evaluated on this machine: cross-play and self-play on the
# 100 held-out kitchens (1 episode per pairing, seat order and kitchen) and the 5 classic ones (4 episodes),
# with the human proxies on their kitchens, and with the scripted cook beside two controls (an untrained
# network one update old, and a partner that always stays put). 400-step episodes, sampled actions, common
# random numbers (the same seed as every earlier evaluation here, so the seeds shipped before, in cec64m/ and
# cec451m/, played the same episodes). Then the paired comparison with those seeds (the same seeds 64M and
# 451M steps in: `compare_crossplay_paired`, the jackknife of the difference matrix over seeds) into
# paired.json, and the README's GIF (the median cross-play episode).
set -euo pipefail
cd "$(dirname "$0")/../../../.."
S=benchmarks/results/overcooked/shipped
W=${WORK:-/tmp/shipped-eval}
mkdir -p "$W"
PY=.venv/bin/python
cec() { .venv/bin/cec "$@"; }
[ -d "$W/random_init" ] || cec train --config configs/train/cec_overcooked_cpu.yaml --max-updates 1 --quiet \
    checkpoint.every_updates=1 run_dir="$W" name=random_init
# the CEC seeds and the human proxies (each plays its own classic kitchen), not the shipped zoo's other
# policies (CEC-Finetune, the kickstarted seeds: their own reports)
"$PY" $S/manifest.py "$W/zoo.yaml" cec human_proxy
"$PY" $S/manifest.py "$W/controls.yaml" cec --controls "$W/random_init"
cec eval --zoo "$W/zoo.yaml" --levels generated --episodes 1 --max-steps 400 --out $S/heldout.csv
cec eval --zoo "$W/zoo.yaml" --levels classic --episodes 4 --max-steps 400 --out $S/classic.csv
# the test set (cec.levels.heldout.test_levels): played once, after the release was chosen on validation
cec eval --zoo "$W/zoo.yaml" --levels test --episodes 1 --max-steps 400 --out $S/test.csv
# the authors' evaluation length (their code plays 100-step episodes; issue 60, item 5): the same three
# tables at 100 steps, kept compressed
mkdir -p $S/steps100
for t in classic:classic:4 heldout:generated:1 test:test:1; do
    IFS=: read -r name levels episodes <<< "$t"
    cec eval --zoo "$W/zoo.yaml" --levels "$levels" --episodes "$episodes" --max-steps 100 \
        --out "$W/steps100-$name.csv"
    bzip2 -9 -c "$W/steps100-$name.csv" > "$S/steps100/$name.csv.bz2"
done
"$PY" $S/parts.py $S .csv > $S/parts.md
"$PY" $S/parts.py $S/steps100 .csv.bz2 > $S/steps100/parts.md
cec eval --zoo "$W/controls.yaml" --levels heldout --episodes 1 --max-steps 400 --pairs with:cook --out $S/with_cook.csv
cec report $S/heldout.csv --out $S/heldout
cec report $S/classic.csv --out $S/classic
"$PY" - $S <<'EOF'
import json, sys
from pathlib import Path
from cec.evaluation.results import read_csv
from cec.evaluation.seeds import seed_matrix
from cec.evaluation.stats import compare_crossplay_paired
S = Path(sys.argv[1])
out = {}
for before_dir in ("cec451m", "cec64m"):
    for name in ("heldout", "classic"):
        now, before = (seed_matrix(read_csv(p)) for p in (S / f"{name}.csv", S / before_dir / f"{name}.csv"))
        a, b = now.summary(now.indices("cec")), before.summary(before.indices("cec"))
        assert a.seeds == b.seeds, (a.seeds, b.seeds)
        c = compare_crossplay_paired(a.matrix, b.matrix)
        out[f"{name}_vs_{before_dir}"] = {"seeds": a.seeds, **c._asdict()}
        print(f"{name}: cross-play {c.mean_a:.1f} now vs {c.mean_b:.1f} in {before_dir}/: {c.diff:+.1f} "
              f"[{c.ci_low:+.1f}, {c.ci_high:+.1f}] (95%, paired jackknife over {c.n_a} seeds, p = {c.p:.2g})")
(S / "paired.json").write_text(json.dumps(out, indent=1) + "\n")
EOF
"$PY" -c "
from pathlib import Path
from apps.reproduce.overcooked.figures import crossplay_gif
from cec.evaluation.results import read_csv
S = Path('$S')
print(crossplay_gif(read_csv(S / 'heldout.csv'), Path('cec/shipped/zoo.yaml'), S / 'cec_xp_heldout.gif'))
"
