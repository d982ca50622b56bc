"""`cec reproduce overcooked [--quick | --cpu | --paper]`: CEC on Overcooked against the paper's baselines.

    cec reproduce overcooked --plan      # every training run, its size and the time it takes here
    cec reproduce overcooked --quick     # the pipeline end to end at a small budget (minutes)
    cec reproduce overcooked             # the CPU version (--cpu): the recipe of docs/reproduce_overcooked.md
    cec reproduce overcooked --paper     # the paper's networks and budgets (a GPU job)

1. **Train** (`cec zoo build`: finished runs are skipped, interrupted ones resumed, so the same command
   continues after any interruption) CEC seeds on the procedural generator (the 100 held-out kitchens and
   the five classic ones excluded), CEC-E3T seeds (the same with E3T's partner), and on each classic
   kitchen IPPO seeds, FCP seeds (population: the IPPO seeds of that kitchen at their first, middle and
   last checkpoints), E3T seeds, and CEC-Finetune from each CEC seed. Every algorithm has the CEC recipe's
   network, so that only the training differs.
2. **Evaluate** (`cec.evaluation.crossplay`, common random numbers, both seat orders, 400-step episodes)
   every agent with every other (cross-play: two seeds of one algorithm, partners they never met; ad hoc:
   two algorithms), with itself (self-play) and with the scripted cook (`cook`, a partner none of them
   trained with), on the five classic kitchens and on the 100 held-out kitchens; on the classic kitchens
   also with the human proxies (`--proxies`, default the shipped `hp_<kitchen>`: behaviour-cloned from
   recorded human games, each in its own kitchen). A single-kitchen agent meets others on its own kitchen
   among the classic ones; on the held-out kitchens each kitchen's agents meet each other and the
   generator-trained agents (`lineups`). Each line-up is cached on its own under its players' checkpoints
   and played between training runs as soon as they are trained (`play_ready`).
3. **Report** `report.md` + `summary.json`: per level set and algorithm the mean team return over seeds
   (each seed's mean over its partners first: seeds are the independent units), SP beside XP beside the
   cook and the human proxies, the paper's values (`paper_overcooked.yaml`, read off its figures) and its
   human study's ordering beside ours, Welch tests of CEC against each baseline on per-seed XP and score
   with the proxies, the cross-algorithm matrices, held-out play by training kitchen, what the failing
   baselines did in training, learning curves (PNG) and a GIF of two CEC seeds in a held-out kitchen;
   `crossplay/report.md` is `cec report` of the agents' table (seed matrices, heatmaps, the meta-game).

The work directory (`--work`, default `runs/reproduce/overcooked-<mode>`) holds the zoo (`zoo/`), its spec
and the result tables; the report goes to `--out` (default `runs/reproduce/overcooked-<mode>/report`, which
git ignores; the committed reports were written with `--out benchmarks/results/overcooked/<mode>`).

The package has the parts of every paper's reproduction (`apps.reproduce.pipeline.PARTS`):

    modes      its versions (quick, CPU, paper): presets, seeds, budgets, measured speeds; the shared names
    paper      the paper's values (`apps/reproduce/paper_overcooked.yaml`) and its human study's ordering
    plan       the `cec zoo build` spec, its runs sized for `--plan`, the runs a work folder trained
    evaluate   the line-ups, the agents', controls' and learning curves' cross-play, cached; episode counts
    summary    per seed scores and CEC against each baseline (seeds as units)
    report     `report.md` and `summary.json`
    command    `cec reproduce overcooked`: the arguments, `--plan` and the steps in order
    sections   (this paper's own) the report's sections after its tests, from the same tables and runs
    figures    (this paper's own) learning curves, the GIF of a median cross-play episode, `cec report`
"""
