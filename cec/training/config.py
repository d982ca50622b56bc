"""The training run's typed, frozen configuration (`cec train --config configs/train/X.yaml key=value`)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from cec.agents.network import NETWORK_PRESETS, NetworkConfig, network_of
from cec.config import ConfigError
from cec.envs.task import EnvConfig
from cec.levels.generator import GeneratorConfig
from cec.paths import safe_name
from cec.training.partners import PartnerConfig
from cec.training.ppo import PPOConfig
from cec.training.tracking import TrackingConfig

#: The upper bound of each size setting (the lower is 1), and of their product per update: far past any run
#: (the paper's is 1 x 512 x 256) and within what one process can hold.
SIZES = (
    ("num_seeds", 1_024),
    ("num_envs", 1 << 20),
    ("num_steps", 1 << 16),
    ("total_env_steps", 10**15),  # what a checkpoint can record (`cec.checkpoints.MAX_COUNT`)
    ("updates_per_call", 10_000),
)
MAX_BATCH_STEPS = 1 << 24
#: The largest magnitude of a game's reward settings (the paper pays 20 a soup).
MAX_REWARD = 1e6

#: algorithm -> (partner kind, trains on a procedural distribution)
ALGORITHMS: dict[str, tuple[str, bool]] = {
    "ippo": ("self_play", False),
    "cec": ("self_play", True),
    "fcp": ("fcp", False),
    "e3t": ("e3t", False),
    "cec_e3t": ("e3t", True),
    "cec_scripted": ("scripted", True),
    "cec_finetune": ("self_play", False),
}


@dataclass(frozen=True)
class CheckpointConfig:
    """When checkpoints are written and which are kept.

    Attributes:
        every_updates: write a checkpoint every this many updates (0: only milestones and the final one).
        keep_last: how many of the most recent non-milestone checkpoints to keep.
        milestones: fractions of the run at which a permanent milestone checkpoint is written
            (FCP populations draw early, middle and final partners from them); 1.0 is the final one.
    """

    every_updates: int = 50
    keep_last: int = 3
    milestones: tuple[float, ...] = (0.0, 0.5, 1.0)

    def __post_init__(self) -> None:
        if self.every_updates < 0 or self.keep_last < 1:
            raise ConfigError("checkpoint.every_updates must be >= 0 and checkpoint.keep_last >= 1")
        if any(not 0.0 <= m <= 1.0 for m in self.milestones):
            raise ConfigError(
                f"checkpoint.milestones are fractions of the run in [0, 1], got {self.milestones}"
            )


def split_paths(text: str) -> tuple[str, ...]:
    """The paths of a comma-separated list (`init_from`); none for an empty one."""
    return tuple(p.strip() for p in text.split(",")) if text else ()


@dataclass(frozen=True)
class TrainConfig:
    """One training run: algorithm, environment, network, PPO, sizes, seeds, checkpoints.

    Attributes:
        algorithm: `ippo` (self-play on one fixed level), `cec` (self-play on a procedural
            distribution), `fcp` (a population partner on one level), `e3t` (E3T's mixture partner on one
            level), `cec_e3t` (E3T's partner on the procedural distribution), `cec_scripted` (the game's
            scripted partner in a share of the episodes, on the procedural distribution) or `cec_finetune`
            (self-play on one level starting from `init_from`, a CEC checkpoint); recorded in checkpoints
            and checked against `env.levels` and `partner.kind`.
        seed: base seed; seed i of the run uses `seed + i`.
        num_seeds: independent seeds trained together in one process (vmapped).
        num_envs: parallel envs per seed.
        num_steps: steps per env per rollout (the paper's NUM_STEPS).
        total_env_steps: joint env steps per seed over the whole run (rounded up to whole updates).
        updates_per_call: updates fused into one compiled call (fewer host round trips; checkpoints,
            metrics rows and interruption happen between calls).
        devices: local devices (GPUs; CPU devices with XLA_FLAGS=--xla_force_host_platform_device_count=N)
            each seed's envs are split over: data-parallel, one set of parameters replicated, the
            gradients all-reduced, the same updates as one device to float rounding. 1: one device; 0:
            every local device. num_envs must split evenly over them.
        network: network preset name (`paper`, `small` or `reference`); the env picks its variant.
        network_overrides: optional explicit widths replacing the preset (all fields of NetworkConfig).
        env: the game and its level distribution.
        ppo: PPO hyper-parameters.
        checkpoint: checkpoint schedule.
        partner: who plays the other seat (`cec.training.partners`): self-play, FCP, E3T.
        init_from: start from this checkpoint's (or run directory's latest) parameters instead of a random
            init (CEC-Finetune, or a CEC policy trained further, e.g. an exported one); the optimizer starts
            fresh. Several checkpoints, comma-separated, one per seed: seed i starts from the i-th; one
            checkpoint of exactly `num_seeds` seeds (and no `init_from_seed`): seed i from its i-th seed.
        init_from_seed: which seed of a multi-seed `init_from` checkpoint (-1: its only seed).
        level_repeats: every this many updates each env draws fresh kitchens; at the updates between, it
            plays the kitchen it is on again (1: fresh kitchens every update, the default). With one
            episode per rollout (num_steps = env.params.max_steps, as in the time-to-skill recipe) each
            kitchen is played `level_repeats` episodes in a row, so a kitchen whose exchange the seats
            stumble on once is there to be tried again (measured in docs/reproduce_overcooked.md: 8 did
            not help). A distribution of levels only; `cec train` only (the distributed learner refuses it).
        tracking: TensorBoard event files (`<run_dir>/<name>/tb/`) and the optional W&B mirror
            (`cec.training.tracking`); where the run's series go, not what it trains.
        run_dir: where runs are written (`<run_dir>/<name>`).
        name: run name (default: `<algorithm>-<env>-<levels>-s<seed>`).
    """

    algorithm: str = "cec"
    seed: int = 0
    num_seeds: int = 1
    num_envs: int = 512
    num_steps: int = 256
    total_env_steps: int = 3_000_000_000
    updates_per_call: int = 1
    devices: int = 1
    network: str = "paper"
    network_overrides: NetworkConfig | None = None
    env: EnvConfig = field(default_factory=EnvConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)
    partner: PartnerConfig = field(default_factory=PartnerConfig)
    init_from: str = ""
    init_from_seed: int = -1
    level_repeats: int = 1
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    run_dir: str = "runs"
    name: str = ""

    def __post_init__(self) -> None:
        if self.name:  # the run's folder under run_dir
            safe_name(self.name, "run name", fix="give name= a plain name and put the folder in run_dir")
        if self.algorithm not in ALGORITHMS:
            raise ConfigError(f"algorithm {self.algorithm!r} is unknown; choose one of {list(ALGORITHMS)}")
        kind, procedural = ALGORITHMS[self.algorithm]
        if procedural != self.env.procedural:
            want = (
                "a distribution of levels (generator / procedural / several kitchen files)"
                if procedural
                else "one fixed level"
            )
            raise ConfigError(
                f"algorithm {self.algorithm} trains on {want}, but env.levels is {self.env.levels!r}"
            )
        if kind != self.partner.kind:
            raise ConfigError(
                f"algorithm {self.algorithm} needs partner.kind {kind!r}, got {self.partner.kind!r}"
            )
        if kind == "scripted" and self.env.game.scripted is None:
            raise ConfigError(
                f"algorithm {self.algorithm} needs a scripted partner, and {self.env.name} has none: "
                "choose another algorithm"
            )
        if self.ppo.teacher_coef > 0 and self.env.game.scripted is None:
            raise ConfigError(
                f"ppo.teacher_coef pulls the policy towards the game's scripted policy, and {self.env.name} "
                "has none: set ppo.teacher_coef to 0"
            )
        if self.partner.scripted_where_needed and self.env.game.needs_partner is None:
            raise ConfigError(
                f"partner.scripted_where_needed needs a game that tells which levels need both seats, and "
                f"{self.env.name} cannot: drop it"
            )
        if self.algorithm == "cec_finetune" and not self.init_from:
            raise ConfigError("algorithm cec_finetune needs init_from (the CEC checkpoint to fine-tune)")
        if len(self.init_from_paths) not in (0, 1, self.num_seeds):
            raise ConfigError(
                f"init_from names {len(self.init_from_paths)} checkpoints for {self.num_seeds} seeds: give "
                "one (every seed starts from it) or one per seed, comma-separated"
            )
        if self.init_from and self.algorithm not in ("cec", "cec_finetune"):
            raise ConfigError(
                f"init_from goes with algorithm cec_finetune (fine-tuning) or cec (continuing a CEC policy's "
                f"training), not {self.algorithm}"
            )
        if self.level_repeats < 1:
            raise ConfigError(
                f"level_repeats must be >= 1 (1: fresh kitchens every update), got {self.level_repeats}"
            )
        if self.level_repeats > 1 and not self.env.procedural:
            raise ConfigError(
                f"level_repeats={self.level_repeats} replays kitchens of a distribution, but env.levels is "
                f"{self.env.levels!r}, one fixed level: leave level_repeats at 1"
            )
        if (
            min(self.num_seeds, self.num_envs, self.num_steps, self.total_env_steps, self.updates_per_call)
            < 1
        ):
            raise ConfigError(
                "num_seeds, num_envs, num_steps, total_env_steps, updates_per_call must be >= 1"
            )
        if self.sequences % self.ppo.num_minibatches:
            raise ConfigError(
                f"{self.sequences} training sequences per update (num_envs x trained seats) must split "
                f"evenly into ppo.num_minibatches = {self.ppo.num_minibatches}"
            )
        if self.devices < 0:
            raise ConfigError(f"devices must be >= 0 (0: every local device), got {self.devices}")
        if self.devices:
            self.check_devices(self.devices)
        if self.network_config.egocentric and not self.env.game.egocentric:
            raise ConfigError(
                "network_overrides.egocentric centres the view on the cell in channel 0, which is the seat's "
                f"own cell only in Overcooked; set it to false for {self.env.name}"
            )
        if self.network_config.region_channels and self.env.name != "overcooked":
            raise ConfigError(
                "network_overrides.region_channels reads Overcooked's observation channels; set it to false "
                f"for {self.env.name}"
            )
        if self.network not in NETWORK_PRESETS:
            raise ConfigError(
                f"unknown network preset {self.network!r}; choose one of {sorted(NETWORK_PRESETS)}"
            )
        self._check_ranges()

    def _check_ranges(self) -> None:
        """Every size within its finite range, the game's reward settings within `MAX_REWARD`, and no
        generator setting where no kitchen comes from the generator (it would be ignored)."""
        for key, hi in SIZES:
            if not 1 <= getattr(self, key) <= hi:
                raise ConfigError(f"{key} must lie in [1, {hi:,}], got {getattr(self, key):,}")
        batch = self.num_seeds * self.num_envs * self.num_steps
        if batch > MAX_BATCH_STEPS:
            raise ConfigError(
                f"num_seeds x num_envs x num_steps = {batch:,} env steps per update is more than "
                f"{MAX_BATCH_STEPS:,} (a rollout's observations alone would take tens of GB); lower num_envs "
                "or num_steps"
            )
        params = self.env.params
        for f in dataclasses.fields(params):
            value = getattr(params, f.name)
            if isinstance(value, float) and not abs(value) <= MAX_REWARD:
                raise ConfigError(
                    f"env.{self.env.name}.{f.name} must lie in [{-MAX_REWARD:g}, {MAX_REWARD:g}], "
                    f"got {value:g}"
                )
        if self.env.name != "overcooked" or self.env.levels != "generator":
            default = GeneratorConfig()
            changed = [
                f.name
                for f in dataclasses.fields(default)
                if getattr(self.env.generator, f.name) != getattr(default, f.name)
            ]
            if changed:
                where = (
                    "Dual Destination" if self.env.name != "overcooked" else f"env.levels={self.env.levels!r}"
                )
                raise ConfigError(
                    f"{', '.join(f'env.generator.{k}' for k in changed)} would be ignored: only the kitchens "
                    "of env.levels=generator (Overcooked) come from the generator, and this run trains on "
                    f"{where}; drop it"
                )

    def check_devices(self, n: int) -> None:
        """A `ConfigError` unless the envs and each minibatch's sequences split evenly over `n` devices
        (each device plays a share of every seed's envs and learns on a share of every minibatch); the
        trainer checks the count it resolves `devices = 0` to as well."""
        share = self.sequences // self.ppo.num_minibatches
        if self.num_envs % n or share % n:
            raise ConfigError(
                f"num_envs {self.num_envs} and each minibatch's {share} sequences must split evenly over the "
                f"{n} devices; change num_envs, ppo.num_minibatches or devices"
            )

    # Derived values (never written back into the config).
    @property
    def init_from_paths(self) -> tuple[str, ...]:
        """The checkpoints of `init_from`: none, one for every seed, or one per seed."""
        return split_paths(self.init_from)

    @property
    def sequences(self) -> int:
        """Training sequences per update and seed: num_envs x trained seats."""
        return self.num_envs * (1 if self.partner.learner_seat_only else 2)

    @property
    def network_config(self) -> NetworkConfig:
        """The preset (or the overrides), with the partner model of `partner.predict_partner`."""
        return network_of(self.network, self.network_overrides, self.env.name, self.partner.predict_partner)

    @property
    def steps_per_update(self) -> int:
        """Joint env steps per seed per update."""
        return self.num_envs * self.num_steps

    @property
    def num_updates(self) -> int:
        return math.ceil(self.total_env_steps / self.steps_per_update)

    @property
    def run_name(self) -> str:
        return self.name or f"{self.algorithm}-{self.env.name}-{self.env.levels_label}-s{self.seed}"

    @property
    def not_the_papers(self) -> tuple[str, ...]:
        """What this run does that the paper's method does not, in words a user reads at start-up (DESIGN
        rule 16): a scripted teacher or partner is a hand-written planner, not cooperation learned from the
        kitchens alone."""
        out = []
        if self.ppo.teacher_coef > 0:
            out.append(
                "learns from the scripted cook as a teacher (a hand-written planner's action is a second "
                "target of the loss, weight "
                f"{self.ppo.teacher_coef:g}"
                + (" falling to 0" if self.ppo.teacher_anneal_env_steps else "")
                + ")"
            )
        if self.partner.kind == "scripted":
            out.append(
                "plays part of its episodes with the scripted cook (a hand-written planner) as partner"
            )
        if self.env.generator.handover_share > 0 and self.env.procedural:
            share = self.env.generator.handover_share
            out.append(f"draws kitchens that need a hand-over more often (handover_share {share:g})")
        return tuple(out)

    @property
    def levels_per_env(self) -> int:
        """Level-buffer depth per env per rollout: enough that no level repeats within a rollout."""
        return self.num_steps // self.env.params.max_steps + 2
