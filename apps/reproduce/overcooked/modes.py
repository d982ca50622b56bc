"""The versions of `cec reproduce overcooked` (quick, CPU, paper): what each trains and plays, and the
names every part of the reproduction shares (algorithms, kitchens, level sets, the controls, the cook).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from cec.agents.zoo import SHIPPED
from cec.levels.classic import CLASSIC_ASCII
from cec.training.config import ALGORITHMS as TRAINING

ROOT = Path(__file__).resolve().parents[3]
KITCHENS = tuple(CLASSIC_ASCII)
ALGORITHMS = ("cec", "cec_e3t", "cec_finetune", "e3t", "fcp", "ippo")
# as the trainer defines them: trained on the generator (they play every kitchen; the others one each), and
# trained with themselves as the partner
GENERALISTS = tuple(a for a in ALGORITHMS if TRAINING[a][1])
SELF_PLAY = tuple(a for a in ALGORITHMS if TRAINING[a][0] == "self_play")
# a kitchen's algorithms in the order their line-ups nest (`evaluate.lineups`: each adds one algorithm's
# agents to those before it, so it plays once they are all trained): FCP, whose runs start from IPPO's
# checkpoints and take longest, last
KITCHEN_ORDER = tuple(
    sorted((a for a in ALGORITHMS if a not in GENERALISTS), key=lambda a: TRAINING[a][0] == "fcp")
)
UNTRAINED, NOOP = "untrained", "noop"  # the controls: partners that learned nothing (`control_policies`)
TITLES = {
    "cec": "CEC", "cec_e3t": "CEC-E3T", "cec_finetune": "CEC-Finetune", "e3t": "E3T", "fcp": "FCP",
    "ippo": "IPPO",
    UNTRAINED: "control: untrained CEC network", NOOP: "control: no-op agent",
}  # fmt: skip
COOK = "cook"
LEVEL_SETS = ("classic", "heldout")
EVAL_STEPS = 400  # the paper's episode length; its absolute scores need it
AUTHORS_STEPS = 100  # the authors' code's evaluation episodes: the report's second table
MEASURED_ON = "the CEC CPU preset, one seed, 2-core AMD EPYC, both cores busy (2.4k steps/s), 2026-11-22"
TTS_MEASURED_ON = (
    "the CPU zoo's runs of the time-to-skill preset, four seeds per process, each run's median env-steps/s "
    "(metrics.csv), 2-core Intel Xeon, both cores busy, 2026-11-28; CEC-Finetune not measured, taken as IPPO "
    "(self-play on one kitchen, the same network and episodes)"
)
MACHINE_FILE = "machine.json"  # the machine and commit that trained and played, in the work folder


@dataclass(frozen=True)
class Mode:
    """One version of the reproduction.

    Attributes:
        name: `quick`, `cpu` or `paper`.
        preset: the CEC preset; every algorithm trains this network (the baselines with overrides).
        seeds: per algorithm; CEC-Finetune fine-tunes each CEC seed (its seeds are the CEC seeds + 100).
        steps: env steps per seed and algorithm (per kitchen for the single-kitchen ones).
        kitchens: the classic kitchens the single-kitchen baselines train on.
        episodes: evaluation episodes per pairing, seat order and level, per level set.
        finetune: overrides of CEC-Finetune (on top of the CEC preset).
        tuned: per algorithm, overrides its tuning probes chose (on top of the preset; docs/
            reproduce_overcooked.md, "Tuning the baselines").
        seconds_per_update: per algorithm, measured seconds of one update of one seed (the basis of
            `--plan`).
        measured_on: where and how they were measured.
        episodes_per_s: measured evaluation episodes (`EVAL_STEPS` steps) per second, per part of
            `planned_episodes` (each level set, the controls, the curves; the basis of `--plan`'s
            cross-play estimate); `eval_measured_on`: where and how.
        overrides: applied to every run (a tiny network in tests).
        generated_levels: held-out generated kitchens played (fewer only in tests).
        proxies: a zoo manifest (or `shipped`) whose `human_proxy` entries play every agent on the classic
            kitchens ('' none); they must have the agents' network (`cec humans bc --preset`).
    """

    name: str
    preset: str
    seeds: dict[str, tuple[int, ...]]
    steps: dict[str, int]
    kitchens: tuple[str, ...] = KITCHENS
    episodes: dict[str, int] = field(default_factory=lambda: {"classic": 4, "heldout": 1})
    finetune: tuple[str, ...] = ("ppo.lr=0.001",)
    tuned: dict[str, tuple[str, ...]] = field(default_factory=dict)
    seconds_per_update: dict[str, float] = field(default_factory=dict)
    measured_on: str = ""
    episodes_per_s: dict[str, float] = field(default_factory=dict)
    eval_measured_on: str = ""
    overrides: tuple[str, ...] = ()
    generated_levels: int = 100
    proxies: str = SHIPPED


QUICK = Mode(
    name="quick",
    preset="configs/train/cec_overcooked_cpu.yaml",
    seeds={
        "cec": (200, 201),
        "cec_e3t": (400, 401),
        "ippo": (0, 1),
        "fcp": (100,),
        "e3t": (150,),
        "cec_finetune": (300, 301),
    },
    steps={
        "cec": 327_680,
        "cec_e3t": 327_680,
        "ippo": 163_840,
        "fcp": 163_840,
        "e3t": 163_840,
        "cec_finetune": 81_920,
    },  # fmt: skip
    kitchens=("cramped_room",),
    episodes={"classic": 2, "heldout": 1},
    seconds_per_update=dict.fromkeys(ALGORITHMS, 6.8),
    measured_on=MEASURED_ON,
    generated_levels=20,
)

CPU = Mode(
    name="cpu",
    # the recipe chosen by cross-play per core-hour (docs/reproduce_overcooked.md, "Time to skill"): the CPU
    # preset's held-out cross-play at 10.5M steps and 0.38 core-h per seed instead of 15M and about 1.7
    preset="configs/train/cec_overcooked_tts.yaml",
    seeds={
        "cec": (200, 201, 202, 203, 204, 205),
        "cec_e3t": (400, 401, 402, 403, 404, 405),
        "ippo": (0, 1, 2, 3, 4, 5),
        "fcp": (100, 101, 102, 103, 104, 105),
        "e3t": (150, 151, 152, 153, 154, 155),
        "cec_finetune": (300, 301, 302, 303, 304, 305),
    },
    # CEC: the recipe's 1,280 updates; IPPO reached 56 per 128-step episode on Cramped Room at 2M steps
    steps={
        "cec": 10_485_760,
        "cec_e3t": 10_485_760,
        "ippo": 1_966_080,
        "fcp": 1_966_080,
        "e3t": 1_966_080,
        "cec_finetune": 983_040,
    },  # fmt: skip
    episodes={"classic": 4, "heldout": 1},
    # the tuning probes' choice (docs/reproduce_overcooked.md, "Tuning the baselines"): FCP and E3T train on
    # the evaluation's 400-step episodes (FCP: no soup with itself on Cramped Room in 128-step ones; E3T:
    # none on Forced Coordination); IPPO keeps CEC's 128 (its cross-play on Cramped Room fell with 400); all
    # keep CEC's LR and shaping (LR 1e-3 and shaping annealed to 0 did worse for FCP and E3T), and E3T its
    # partner's epsilon 0.55 (0.3 did worse on Counter Circuit)
    tuned={"fcp": ("env.overcooked.max_steps=400",), "e3t": ("env.overcooked.max_steps=400",)},
    seconds_per_update={
        "cec": 1.14,
        "cec_e3t": 0.82,
        "ippo": 1.13,
        "cec_finetune": 1.13,
        "fcp": 1.65,
        "e3t": 0.92,
    },
    measured_on=TTS_MEASURED_ON,
    # the CPU zoo's own evaluation (logs in benchmarks/results/overcooked/cpu/work/logs): classic 13,520
    # episodes in 509 s (before the cook's games were split off, 92a0115), held-out 280,100 in 1,933 s,
    # controls 4,200 in 100 s, curves 16,000 in 136 s
    episodes_per_s={"classic": 26.6, "heldout": 145.0, "controls": 42.0, "curves": 118.0},
    eval_measured_on="the CPU zoo's own evaluation on the 2-vCPU Intel Xeon, both cores, 2026-11-28",
)

PAPER = Mode(
    name="paper",
    preset="configs/train/cec_overcooked.yaml",
    seeds=CPU.seeds,
    steps={
        "cec": 3_000_000_000,
        "cec_e3t": 3_000_000_000,
        "ippo": 100_000_000,
        "fcp": 100_000_000,
        "e3t": 100_000_000,
        "cec_finetune": 100_000_000,
    },  # fmt: skip
    finetune=("ppo.lr=0.00003",),
)

MODES = {"quick": QUICK, "cpu": CPU, "paper": PAPER}
