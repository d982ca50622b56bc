"""`cec reproduce dual-destination`: the paper's Dual Destination results, end to end.

    cec reproduce dual-destination --plan      # what would be trained and evaluated, and how long it takes
    cec reproduce dual-destination --quick     # a reduced version (under 30 minutes on a 2-core CPU)
    cec reproduce dual-destination             # the full version, sized for a CPU (--plan states its time)
    cec reproduce dual-destination --paper     # the paper's networks and budgets (a GPU job)

For each variant of the game (fully observable, partially observable 3x3 view, multi-task green + pink):

1. **Train** (`cec zoo build`, resumable: run the same command again after an interruption; several
   processes may share it, one per core, and `--train-only` stops each before step 2) IPPO seeds
   and FCP seeds on the fixed task (the multi-task layout for the multi-task variant; FCP's population is
   the IPPO seeds at their first, middle and last milestones), and CEC seeds on procedurally generated
   tasks, the fixed tasks and the 100 evaluation tasks held out of its training.
2. **Evaluate** cross-play (`cec.evaluation.crossplay`, common random numbers, both seat orders) on the
   fixed task and on the 100 held-out generated tasks: every pair of different seeds of one algorithm
   (zero-shot coordination with unseen partners, the paper's measure), self-play, and every policy with
   the scripted oracle partner (`dd_oracle`) as a reference point.
3. **Report** (`summary.py`, `report.py`) `report.md` (+ `summary.json`, bar plots) beside the
   paper's numbers (`paper_dual_destination.yaml`, through `paper.py`): per variant, task set
   and algorithm the normalised cross-play score (return / 200) with its standard error over seeds (each
   seed's mean with the other seeds); the paper's orderings with Welch t-tests and bootstrap intervals over
   those per-seed means (seeds are the independent units; pairs share seeds); and, where a number
   differs from the paper's by more than 0.05, by how much.

The work directory (`--work`, default `runs/reproduce/dual_destination-<mode>`) holds one zoo per
variant (`<variant>/zoo`), its spec and the result tables; the report goes to `--out` (default
`benchmarks/results/dual_destination/<mode>`).

The package has the parts of every paper's reproduction (`apps.reproduce.pipeline.PARTS`):

    modes      its versions (quick, full, paper): presets, seeds, budgets per variant, measured speeds
    paper      the paper's numbers, orderings and ablations (`apps/reproduce/paper_dual_destination.yaml`)
    plan       each variant's `cec zoo build` spec, its runs sized for `--plan`, training (`--train-only`)
    evaluate   each variant's cross-play with the oracle partner, cached while nothing it depends on changed
    summary    the scores, conventions, ordering tests and training statistics computed from the runs
    report     `report.md`, `summary.json`, bar plots and learning curves beside the paper's numbers
    command    `cec reproduce dual-destination`: the arguments, `--plan` and the steps in order
    reasons    (this paper's own) why a number differs from the paper's or an ordering fails, read from the
               same seeds' other measures; the report puts these lines under its tables
"""
