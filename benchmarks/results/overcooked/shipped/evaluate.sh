#!/usr/bin/env bash
# The shipped CEC seeds (cec/shipped/zoo.yaml) evaluated on this machine: cross-play and self-play on the
# 100 held-out kitchens (1 episode per pairing, seat order and kitchen) and the 5 classic ones (4 episodes),
# with the human proxies on their kitchens, and with the scripted cook beside two controls (an untrained
# network one update old, and a partner that always stays put). 400-step episodes, sampled actions.
set -euo pipefail
cd "$(dirname "$0")/../../../.."
S=benchmarks/results/overcooked/shipped
W=${WORK:-/tmp/shipped-eval}
mkdir -p "$W"
cec() { .venv/bin/cec "$@"; }
[ -d "$W/random_init" ] || cec train --config configs/train/cec_overcooked_cpu.yaml --max-updates 1 --quiet \
    checkpoint.every_updates=1 run_dir="$W" name=random_init
cec eval --zoo cec/shipped/zoo.yaml --levels generated --episodes 1 --max-steps 400 --out $S/heldout.csv
cec eval --zoo cec/shipped/zoo.yaml --levels classic --episodes 4 --max-steps 400 --out $S/classic.csv
{ grep -v '^#' cec/shipped/zoo.yaml | sed "s|checkpoint: \(cec64m-s20.\)|checkpoint: $PWD/cec/shipped/\1|" \
    | awk '/^- name: hp_/{exit} {print}'
  echo "- {name: random_init, algorithm: random_init, seed: 0, checkpoint: $W/random_init}"
  echo "- {name: noop, scripted: noop}"
  echo "- {name: cook, scripted: cook}"; } > "$W/controls.yaml"
cec eval --zoo "$W/controls.yaml" --levels heldout --episodes 1 --max-steps 400 --pairs with:cook --out $S/with_cook.csv
cec report $S/heldout.csv --out $S/heldout
cec report $S/classic.csv --out $S/classic
