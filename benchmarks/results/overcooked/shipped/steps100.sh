#!/usr/bin/env bash
# The shipped releases at the authors' evaluation length (their code plays 100-step episodes; ours 400; issue
# 86, item 3), the same protocol, seeds and draws as each release's 400-step tables, kept compressed beside
# them:
# - the kickstarted seeds (teach21m, `cec_teacher`; teacher/evaluate.sh's protocol): the 100 generated
#   validation kitchens (1 episode per pairing, seat order and kitchen), the classic five (4) and the test
#   set (1), into teacher/steps100/ with parts.md (the 758M seeds' own: evaluate.sh, steps100/);
# - each fine-tuned family (finetune/evaluate.py's protocol, 4 episodes per pairing and seat order in its
#   kitchen): the shipped fine-tuned partner of each kitchen with itself, the generalist seeds it started
#   from, the kitchen's test human proxy and the scripted cook, and those with each other, into
#   finetune/steps100/ (ft758m) and finetune/teacher/steps100/ (ftteach), then steps100.md beside each.
# The test set's read is recorded in cec/levels/data/test_reads.csv. STEPS100_ONLY=teacher|finetune runs one.
set -euo pipefail
cd "$(dirname "$0")/../../../.."
S=benchmarks/results/overcooked/shipped
W=${WORK:-/tmp/shipped-steps100}
mkdir -p "$W"
PY=.venv/bin/python
cec() { .venv/bin/cec "$@"; }
only=${STEPS100_ONLY:-}
if [ -z "$only" ] || [ "$only" = teacher ]; then
    T=$S/teacher/steps100
    mkdir -p $T
    "$PY" $S/manifest.py "$W/teach.yaml" cec_teacher
    for t in heldout:generated:1 classic:classic:4 test:test:1; do
        IFS=: read -r name levels episodes <<< "$t"
        cec eval --zoo "$W/teach.yaml" --levels "$levels" --episodes "$episodes" --max-steps 100 \
            --out "$W/teach-$name.csv"
        bzip2 -9 -c "$W/teach-$name.csv" > "$T/$name.csv.bz2"
    done
    "$PY" -c "
from cec.checkpoints import code_version
from cec.levels.ledger import record
record('test', 'the kickstarted seeds teach21m-s400..403 at the authors\' 100-step episodes, 1 episode per pairing and kitchen',
       'benchmarks/results/overcooked/shipped/steps100.sh', code_version(short=True))"
    "$PY" $S/parts.py $T .csv.bz2 cec_teacher > $T/parts.md
fi
if [ -z "$only" ] || [ "$only" = finetune ]; then
    for fam in ft758m:cec:finetune ftteach:cec_teacher:finetune/teacher; do
        IFS=: read -r prefix generalist folder <<< "$fam"
        mkdir -p "$S/$folder/steps100"
        for k in cramped_room asymm_advantages coord_ring forced_coord counter_circuit; do
            "$PY" - "$W/$prefix-$k.yaml" "$prefix-$k" "$generalist" "hp_$k" <<'PYEOF'
import sys, yaml
from cec.agents.zoo import SHIPPED_ZOO
out, partner, generalist, proxy = sys.argv[1:]
shipped = yaml.safe_load(SHIPPED_ZOO.read_text())["policies"]
keep = [e for e in shipped if e["name"] in (partner, proxy) or e["algorithm"] == generalist]
keep = [{**e, "checkpoint": str(SHIPPED_ZOO.parent / e["checkpoint"])} for e in keep]
yaml.safe_dump({"policies": [*keep, {"name": "cook", "scripted": "cook"}]}, open(out, "w"), sort_keys=False)
PYEOF
            cec eval --zoo "$W/$prefix-$k.yaml" --levels "$k" --episodes 4 --max-steps 100 --out "$W/$prefix-$k.csv"
            bzip2 -9 -c "$W/$prefix-$k.csv" > "$S/$folder/steps100/$k.csv.bz2"
        done
        "$PY" $S/steps100_finetune.py "$prefix" > "$S/$folder/steps100/steps100.md"
    done
fi
