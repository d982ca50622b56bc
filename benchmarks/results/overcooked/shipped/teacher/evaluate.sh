#!/usr/bin/env bash
# The shipped kickstarted seeds (cec/shipped/teach21m-s400..403, algorithm `cec_teacher`) evaluated as the
# shipped CEC seeds are (../evaluate.sh: 400-step episodes, sampled actions, the same evaluation seed, both
# seat orders; 1 episode per pairing and kitchen on the 100 held-out kitchens and the test set, 4 on the 5
# classic ones), with the scripted cook beside its two controls (an untrained network of the recipe, one
# update old, and a partner that always stays put), and with the human proxies on their kitchens.
set -euo pipefail
cd "$(dirname "$0")/../../../../.."
S=benchmarks/results/overcooked/shipped
T=$S/teacher
W=${WORK:-/tmp/shipped-teacher-eval}
mkdir -p "$W"
PY=.venv/bin/python
cec() { .venv/bin/cec "$@"; }
[ -d "$W/random_init" ] || cec train --config configs/train/cec_overcooked_teacher.yaml --max-updates 1 --quiet \
    checkpoint.every_updates=1 run_dir="$W" name=random_init
"$PY" $S/manifest.py "$W/seeds.yaml" cec_teacher
"$PY" $S/manifest.py "$W/proxies.yaml" cec_teacher human_proxy
"$PY" $S/manifest.py "$W/controls.yaml" cec_teacher --controls "$W/random_init"
cec eval --zoo "$W/seeds.yaml" --levels generated --episodes 1 --max-steps 400 --out "$W/heldout.csv"
cec eval --zoo "$W/seeds.yaml" --levels classic --episodes 4 --max-steps 400 --out "$W/classic.csv"
# the test set (cec.levels.heldout.test_levels): played once, after the recipe was chosen on validation
cec eval --zoo "$W/seeds.yaml" --levels test --episodes 1 --max-steps 400 --out "$W/test.csv"
for k in cramped_room asymm_advantages coord_ring forced_coord counter_circuit; do
    cec eval --zoo "$W/proxies.yaml" --levels $k --episodes 4 --max-steps 400 --pairs with:hp_$k --out "$W/proxy_$k.csv"
done
"$PY" - "$W" <<'PYEOF'
import sys
from pathlib import Path
from cec.evaluation.results import read_csv, write_csv
work = Path(sys.argv[1])
write_csv(read_csv(sorted(work.glob("proxy_*.csv"))), work / "with_proxies.csv")
PYEOF
cec eval --zoo "$W/controls.yaml" --levels heldout --episodes 1 --max-steps 400 --pairs with:cook --out "$W/with_cook.csv"
for t in heldout classic test with_proxies with_cook; do bzip2 -9 -c "$W/$t.csv" > "$T/$t.csv.bz2"; done
"$PY" $S/parts.py $T .csv.bz2 cec_teacher > $T/parts.md
cec report $T/heldout.csv.bz2 --out $T/heldout
cec report $T/classic.csv.bz2 --out $T/classic
