"""The versions of `cec reproduce dual-destination` (quick, full, paper): what each trains and plays.

`Mode` is one version's presets, seeds, budgets per variant, evaluation episodes and the seconds per
update measured for its `--plan` estimate; `command` trains, evaluates and reports it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from apps.reproduce.dual_destination.paper import ABLATIONS, VARIANTS


@dataclass(frozen=True)
class Mode:
    """What one version of the reproduction trains and plays.

    Attributes:
        name: `quick` or `full`.
        presets: training preset per algorithm (`configs/train/...`), in training order.
        seeds: seeds per algorithm and ablation (FCP's population is every IPPO seed, as in the paper's
            code).
        steps: env steps per seed, per variant and algorithm (and ablation).
        episodes: episodes per pairing, seat order and level, per level set.
        seconds_per_update: measured seconds of one training update per algorithm's preset (one seed;
            `num_seeds` seeds vmapped in one process take about that many times as long on a CPU); the
            basis of `--plan`'s estimate.
        measured_on: where and how `seconds_per_update` was measured.
        overrides: `key=value` overrides applied to every training run (e.g. a smaller network in tests).
        generated_levels: how many of the 100 held-out generated tasks to play (fewer only in tests).
        variants: the variants run when `--variants` is not given.
        why: the report's paragraph after the differences from the paper's numbers: what this version is
            (its sizes against the paper's budgets), so what its differences can and cannot show; none
            when empty.
        ablations: `paper.ABLATIONS` it trains after the algorithms (each its algorithm's preset with
            the ablation's overrides last) and reports as more rows.
    """

    name: str
    presets: dict[str, str]
    seeds: dict[str, tuple[int, ...]]
    steps: dict[str, dict[str, int]]
    episodes: dict[str, int]
    seconds_per_update: dict[str, float] = field(default_factory=dict)
    measured_on: str = ""
    overrides: tuple[str, ...] = ()
    generated_levels: int = 100
    variants: tuple[str, ...] = VARIANTS
    why: str = ""
    ablations: tuple[str, ...] = ()

    @property
    def rows(self) -> tuple[str, ...]:
        """The algorithms and ablations this version trains and reports, in training order."""
        return (*self.presets, *self.ablations)


def algorithm_of(row: str) -> str:
    """The algorithm a row trains: an ablation's (`cec_nolstm` -> `cec`), else the row itself."""
    return ABLATIONS[row].algorithm if row in ABLATIONS else row


QUICK = Mode(
    name="quick",
    presets={
        "ippo": "configs/train/dd_ippo_quick.yaml",
        "fcp": "configs/train/dd_fcp_quick.yaml",
        "cec": "configs/train/dd_cec_quick.yaml",
    },
    seeds={"ippo": (0, 1, 2), "fcp": (100, 101, 102), "cec": (200, 201, 202)},
    steps={v: {"ippo": 256_000, "fcp": 256_000, "cec": 768_000} for v in VARIANTS},
    episodes={"fixed": 8, "generated": 1},
    variants=("full_obs",),  # ~25 minutes; each further variant (--variants) adds about as much
    # from the quick run's own metrics (3 seeds vmapped, per seed), load 4-9
    seconds_per_update={"ippo": 1.7, "fcp": 1.3, "cec": 7.1},
    measured_on="the project's 2-core AMD EPYC CPU, 3 seeds vmapped, other jobs running (load 4-9), "
    "2026-11-21",
    why="Why: this is the reduced version, sized to finish within 30 minutes on a 2-core CPU: per seed "
    "2.56e5 (IPPO, FCP) and 7.68e5 (CEC) env steps with small networks, against the paper's 1e8-3e8 "
    "steps with its larger network, and 3 seeds per algorithm (3 XP pairs). The Training section "
    "shows how far each algorithm got: where CEC's training return at the end is still low, its "
    "policy has not yet learned the generated tasks, and its XP numbers measure an untrained policy. The "
    "quick version checks the pipeline, not the paper's values.",
)

FULL = Mode(
    name="full",
    presets={
        "ippo": "configs/train/dd_ippo_cpu.yaml",
        "fcp": "configs/train/dd_fcp_cpu.yaml",
        "cec": "configs/train/dd_cec_cpu.yaml",
    },
    ablations=("cec_nolstm",),
    seeds={
        "ippo": (0, 1, 2, 3, 4, 5),
        "fcp": (100, 102, 104, 106),  # not consecutive: one run per seed, which two processes can share
        "cec": (200, 201, 202, 203),
        "cec_nolstm": (300, 302, 304, 306),
    },
    # CEC partially observed: 6e6, as at 3e6 two of its four seeds had not taken off (one never left
    # -0.49, one had just begun; benchmarks/results/dual_destination/partial_obs_3e6/); multi-task: 6e6 too,
    # as the version before (no LSTM) was still rising at 0.62 after 2e6 there (docs/reproduce.md). The
    # ablation stays at 3e6 (partially observed one of its seeds reached 0.92 by then, which answers the
    # paper's claim; its XP test against CEC then favours CEC's longer training, as the report says)
    steps={
        v: {
            "ippo": 3_000_000,
            "fcp": 3_000_000,
            "cec": 3_000_000 if v == "full_obs" else 6_000_000,
            "cec_nolstm": 3_000_000,
        }
        for v in VARIANTS
    },
    episodes={"fixed": 16, "generated": 2},
    # the full run's own metrics (fully observable, 2026-11-24; two zoo builds, one per core): IPPO 6
    # vmapped seeds 32.4 min, FCP one run per seed 14.5 min in all, CEC 4 vmapped seeds 107.4 min, the
    # ablation one run per seed 75.7 min in all
    seconds_per_update={"ippo": 1.4, "fcp": 0.9, "cec": 6.9, "cec_nolstm": 4.8},
    measured_on="the project's 2-core Intel Xeon CPU (no GPU), one run per core, 2026-11-24",
    why="Why, in general: this version is sized for a CPU (docs/reproduce.md): an LSTM for every algorithm "
    "(CEC with a small version of the paper's CNN, IPPO and FCP with an MLP encoder), 3e6 env steps per "
    "seed (6e6 for CEC partially observed and multi-task) against the paper's 1e8-3e8, LR 1e-3 with 8 x 8 "
    "minibatch updates per rollout, and gamma 0.9 for CEC (0.99 for IPPO and FCP, as in the paper). Each "
    "line above says what the same seeds' self-play and oracle-partner scores show.",
)

PAPER_SCALE = Mode(
    name="paper",
    presets={
        "ippo": "configs/train/dd_ippo.yaml",
        "fcp": "configs/train/dd_fcp.yaml",
        "cec": "configs/train/dd_cec.yaml",
    },
    seeds={"ippo": (0, 1, 2, 3, 4, 5), "fcp": (100, 101, 102, 103), "cec": (200, 201, 202, 203)},
    steps={
        "full_obs": {"ippo": 100_000_000, "fcp": 100_000_000, "cec": 100_000_000},
        "partial_obs": {"ippo": 300_000_000, "fcp": 300_000_000, "cec": 300_000_000},
        "multi_task": {"ippo": 300_000_000, "fcp": 300_000_000, "cec": 300_000_000},
    },
    episodes={"fixed": 32, "generated": 4},
    # `cec train` with each preset, one seed, 3 updates of 512 envs x 100 steps (FCP with 18 partners)
    seconds_per_update={"ippo": 92.0, "fcp": 150.0, "cec": 78.0},
    measured_on="the project's 2-core AMD EPYC CPU (no GPU), one seed, other jobs running (load 4-5), "
    "2026-11-21",
    why="Why: this version has the paper's networks and budgets, so a difference is in what the seeds "
    "learned; each line above says what their self-play and oracle-partner scores show.",
)

MODES = {"quick": QUICK, "full": FULL, "paper": PAPER_SCALE}
