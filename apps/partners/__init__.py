"""`cec partners`: which shipped partner plays where, chosen on validation and reported on test by product
commands (DESIGN.md rules 13 and 15): what they ship is what `cec play serve` loads.

    cec partners finetune --family ftteach --runs runs/ftteach --ship   # each kitchen's fine-tuned seed
    cec partners best --ship                                           # cec/shipped/best.yaml

- `finetune` (`apps.partners.finetune`): per classic kitchen, the seed of a fine-tuned run that ships as
  `cec/shipped/<family>-<kitchen>`, with the family's table beside the seeds it started from.
- `best` (`apps.partners.best`): per classic kitchen, which shipped partner `--partner best` plays (a
  fine-tuned agent or a group of generalist seeds), and the generalists of every other kitchen.

Both choose with the kitchens' validation proxies (`bc_<kitchen>`, cloned by `cec humans bc` from the train
games' players) and report with the test proxies (`hp_<kitchen>`, shipped); a choice without its figures
stops the command (`cec.evaluation.choice`: exit 2, nothing written or shipped). The tables they play stay in
`--out` (`apps.partners.tables`), so a second call chooses again without playing.
"""

from __future__ import annotations

import argparse

from apps.partners import best, finetune


def add_subcommands(sub: argparse._SubParsersAction) -> None:
    """Registers `cec partners best|finetune` on the `cec` command's subparsers."""
    partners = sub.add_parser(
        "partners", help="choose the shipped partners on validation: the fine-tuned seeds, --partner best"
    )
    partners_sub = partners.add_subparsers(dest="partners_command", required=True)
    best.add_parser(partners_sub)
    finetune.add_parser(partners_sub)
