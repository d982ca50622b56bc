"""A zoo manifest of shipped policies for an evaluation: the entries of `cec/shipped/zoo.yaml` of each
algorithm named, in that order, with their checkpoints' paths made absolute; with `--controls`, the scripted
cook's two controls and the cook after them (an untrained network one update old, the checkpoint given, and a
partner that always stays put):

    .venv/bin/python benchmarks/results/overcooked/shipped/manifest.py OUT.yaml cec human_proxy
    .venv/bin/python benchmarks/results/overcooked/shipped/manifest.py OUT.yaml cec --controls RANDOM_INIT
"""

from __future__ import annotations

import argparse

import yaml

from cec.agents.zoo import SHIPPED_ZOO


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out")
    ap.add_argument("algorithms", nargs="+")
    ap.add_argument("--controls", metavar="RANDOM_INIT", help="an untrained run's checkpoint or run")
    args = ap.parse_args()
    shipped = yaml.safe_load(SHIPPED_ZOO.read_text())["policies"]
    entries = [
        {**e, "checkpoint": str(SHIPPED_ZOO.parent / e["checkpoint"])}
        for algorithm in args.algorithms
        for e in shipped
        if e["algorithm"] == algorithm
    ]
    if args.controls:
        entries += [
            {"name": "random_init", "algorithm": "random_init", "seed": 0, "checkpoint": args.controls},
            {"name": "noop", "scripted": "noop"},
            {"name": "cook", "scripted": "cook"},
        ]
    with open(args.out, "w") as f:
        yaml.safe_dump({"policies": entries}, f, sort_keys=False)


if __name__ == "__main__":
    main()
