"""The study configuration of `cec play`: who the partners are, which kitchens, the flow, the survey, storage.

A study is one YAML file (`configs/study/*.yaml`), loaded strictly by `load_study` (unknown keys, wrong
types and inconsistent values are `ConfigError`s that name the key and the fix). Paths inside it
(checkpoints, zoo manifests) are relative to the file's folder.

    name: counter_circuit_ring          # storage namespace; letters, digits, '_' and '-'
    levels: [counter_circuit, coord_ring]   # each participant is assigned one, in turn
    partners:                            # each is played `rounds_per_partner` times, order shuffled
      - {name: cec, zoo: ../../zoos/main/zoo.yaml, group: cec}   # a random seed of the group per round
      - {name: e3t, checkpoint: ../../runs/e3t-cc-s0}
    practice: {partner: cec, level: cramped_room, steps: 50}
    env: {max_steps: 200, random_start_facing: false}           # the round length is env.max_steps
    limits: {joins_per_address_per_minute: 20, max_active_participants: 500}   # bounds on anonymous joins
    survey: {items: [{id: enjoyed, text: I enjoyed playing with my partner.}, ...]}

Level specs (`levels`, `practice.level`): a classic kitchen (`counter_circuit`, ...), a held-out kitchen
(`generated_000` .. `generated_099`), a freshly generated one (`generated:SEED`, or `generated:random` for
a new draw every round), or a path to an ASCII kitchen file.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from cec.config import ConfigError, load_config
from cec.envs.overcooked import EnvParams
from cec.paths import safe_name

MODES = ("turn_based", "real_time")
AGENT_ACTIONS = ("greedy", "sampled")
MAX_TICKS_PER_SECOND = 30.0
MAX_STEPS = 10_000
MAX_LIMIT = 10_000_000
MAX_RECORD_BYTES = 1 << 50  # a PiB: the byte caps' ceiling (they are checked, never reached by accident)
MIN_RECORD_BYTES = 4_096  # a round's start alone records about 2 kB
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")
_ID = re.compile(r"^[a-z][a-z0-9_]{0,31}$")

#: The 5-point agreement scale of the paper's post-round survey.
LIKERT_5 = ("Strongly disagree", "Disagree", "Neither agree nor disagree", "Agree", "Strongly agree")


@dataclass(frozen=True)
class PartnerSpec:
    """One partner condition. Its name goes into the records; participants only see "Partner 1", "2", ...

    Exactly one of `checkpoint`, `zoo` and `random_init` says where the policy comes from.

    Attributes:
        name: label in the records and in the exported result table (`policy_b`), unique in the study.
        checkpoint: a checkpoint directory, or a run directory (its latest checkpoint).
        seed: with `checkpoint`, the seed to play out of a multi-seed checkpoint (null: its only seed).
        zoo: a zoo manifest (`cec zoo build` writes one); a policy is drawn from it for every round.
        group: with `zoo`, draw only among the entries of this algorithm, or the entry of this name
            ('' : any entry). `zoo: shipped` is the zoo shipped with the package (`cec/shipped/`).
        random_init: a randomly initialised network (a chance-level partner for demos and tests).
        network: with `random_init`, the network preset (`small`, `reference`, `paper`).
        init_seed: with `random_init`, the initialisation seed.
    """

    name: str
    checkpoint: str = ""
    seed: int | None = None
    zoo: str = ""
    group: str = ""
    random_init: bool = False
    network: str = "small"
    init_seed: int = 0

    def __post_init__(self) -> None:
        if not _NAME.match(self.name):
            raise ConfigError(
                f"partner name {self.name!r} must be 1-64 letters, digits, '_' or '-' (it is a record label)"
            )
        sources = [bool(self.checkpoint), bool(self.zoo), self.random_init]
        if sum(sources) != 1:
            raise ConfigError(
                f"partner {self.name!r} needs exactly one source: `checkpoint: DIR`, `zoo: MANIFEST` "
                "(with an optional `group`), or `random_init: true`"
            )
        if self.group and not self.zoo:
            raise ConfigError(f"partner {self.name!r}: `group` selects entries of a `zoo`; give the zoo")
        if self.seed is not None and not self.checkpoint:
            raise ConfigError(
                f"partner {self.name!r}: `seed` picks a seed of a `checkpoint`; give the checkpoint"
            )


@dataclass(frozen=True)
class PracticeConfig:
    """The practice round, played before the study rounds; recorded, but not surveyed and not exported.

    Attributes:
        partner: name of one of the study's partners ('' : the first).
        level: level spec (see the module docstring).
        steps: length of the practice round in steps.
        mode: `turn_based` or `real_time` ('' : the study's mode).
    """

    partner: str = ""
    level: str = "cramped_room"
    steps: int = 50
    mode: str = ""

    def __post_init__(self) -> None:
        if not 1 <= self.steps <= MAX_STEPS:
            raise ConfigError(f"practice.steps must lie in [1, {MAX_STEPS}], got {self.steps}")
        if self.mode and self.mode not in MODES:
            raise ConfigError(f"practice.mode {self.mode!r} is unknown; choose one of {list(MODES)} or ''")


@dataclass(frozen=True)
class SurveyItem:
    """One Likert statement of the post-round survey.

    Attributes:
        id: the answer's key in the records (lowercase letters, digits and '_').
        text: the statement shown to the participant.
    """

    id: str
    text: str

    def __post_init__(self) -> None:
        if not _ID.match(self.id):
            raise ConfigError(f"survey item id {self.id!r} must be lowercase letters, digits or '_' (<= 32)")
        if not self.text.strip():
            raise ConfigError(f"survey item {self.id!r} has no text")


#: The paper's seven post-round questions (appendix "User Assessments"), as agreement statements.
PAPER_SURVEY = (
    SurveyItem("adapted", "My partner adapted to what I was doing."),
    SurveyItem("consistent", "My partner behaved consistently."),
    SurveyItem("human_like", "My partner played like a human would."),
    SurveyItem("in_my_way", "My partner got in my way."),
    SurveyItem("frustrating", "Playing with my partner was frustrating."),
    SurveyItem("enjoyed", "I enjoyed playing with my partner."),
    SurveyItem("coordination", "My partner coordinated well with me."),
)


@dataclass(frozen=True)
class SurveyConfig:
    """The survey after every study round (none after the practice round).

    Attributes:
        prompt: the line above the statements.
        scale: the answer labels, lowest first; answers are recorded as 1..len(scale).
        items: the statements; empty: no survey.
    """

    prompt: str = "How much do you agree with each statement about the partner you just played with?"
    scale: tuple[str, ...] = LIKERT_5
    items: tuple[SurveyItem, ...] = PAPER_SURVEY

    def __post_init__(self) -> None:
        if not 2 <= len(self.scale) <= 11:
            raise ConfigError(f"survey.scale must have 2 to 11 labels, got {len(self.scale)}")
        ids = [item.id for item in self.items]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"survey item ids must be unique, got {ids}")


@dataclass(frozen=True)
class InfoField:
    """A piece of information the study asks of each participant (and the only personal data it keeps).

    Attributes:
        id: the key in the records (lowercase letters, digits and '_').
        label: the question shown.
        pattern: a regular expression the whole answer must match ('' : any text).
        max_length: longest accepted answer, in characters.
        required: an empty answer is refused.
    """

    id: str
    label: str
    pattern: str = ""
    max_length: int = 64
    required: bool = True

    def __post_init__(self) -> None:
        if not _ID.match(self.id):
            raise ConfigError(f"ask[].id {self.id!r} must be lowercase letters, digits or '_' (<= 32)")
        if not 1 <= self.max_length <= 1000:
            raise ConfigError(f"ask[{self.id}].max_length must lie in [1, 1000], got {self.max_length}")
        try:
            re.compile(self.pattern)
        except re.error as err:
            raise ConfigError(f"ask[{self.id}].pattern is not a valid regular expression: {err}") from err


@dataclass(frozen=True)
class StorageConfig:
    """Where the records go. Every event is written before the server answers the action that caused it.

    Attributes:
        dir: folder for the append-only JSON-lines files, one per participant (fsynced per event);
            '' : no files (then `redis_url` is required). Relative to the current directory.
        redis_url: also (or only) append every event to a Redis stream per participant
            (`redis://host:port/db`; '' : no Redis). The password comes from CEC_REDIS_PASSWORD.
        key_prefix: prefix of the Redis keys (`<prefix>:play:<study>:...`).
        redis_timeout_s: how long one Redis command (or connecting) may take before it is retried once and
            then the participant's action is answered 503. Short, because each waiting action holds one of
            the server's few worker threads, which every participant's steps share: with Redis frozen, a
            long wait per action would stall the game for everyone.
    """

    dir: str = "play_data"
    redis_url: str = ""
    key_prefix: str = "cec"
    redis_timeout_s: float = 1.0

    def __post_init__(self) -> None:
        if not self.dir and not self.redis_url:
            raise ConfigError(
                "storage needs a place for the records: set storage.dir and/or storage.redis_url"
            )
        if not self.redis_timeout_s > 0:
            raise ConfigError(
                f"storage.redis_timeout_s must be > 0 s (got {self.redis_timeout_s}); the default is 1.0"
            )


@dataclass(frozen=True)
class LimitsConfig:
    """Bounds on what anonymous clients can make the server hold. `POST /api/join` is open to anyone who
    can reach the port, so new participants are admitted only within these bounds; a join beyond one is
    refused with HTTP 429 (a rate) or 503 (the server is full) and a JSON error naming the key. A
    participant who has joined is never refused by them (reloads, rounds and forms go on).

    Attributes:
        joins_per_address_per_minute: new participants one client address may start: this many at once,
            then this many a minute (a token bucket). The address is the connection's peer, or the
            client that a proxy on the same machine names in X-Forwarded-For; participants behind one
            NAT (a lab) share it, so raise it for a lab session.
        max_active_participants: participants in progress at once (joined, not finished or declined,
            and seen within `idle_minutes`); joins beyond it get 503 until one finishes or goes idle.
        idle_minutes: a participant with no request for this long stops counting as active (they can
            still come back and continue).
        max_participants: participants this server holds in all, those taken back from the records of
            earlier runs included; joins beyond it get 503 (each costs memory and a record file).
        max_rounds_per_participant: free play: rounds one participant may play; past it the page says so
            and starts no more (a 200-step round takes a person a minute or two).
        max_reconnects_per_participant: times one participant's rounds may be started again (a reload, a
            dropped connection, a second tab: each records the round's start again); past it no round
            starts for them, and the page says so.
        max_record_bytes_per_participant: bytes of records one participant may make (a 200-step round
            records about 70 kB); past it no round starts for them (the round under way is recorded to its
            end), and the page says so.
        max_record_bytes: bytes of records this server may hold in all, those of earlier runs included;
            past it no round starts and joins get 503.
    """

    joins_per_address_per_minute: int = 20
    max_active_participants: int = 500
    idle_minutes: float = 30.0
    max_participants: int = 10_000
    max_rounds_per_participant: int = 500
    max_reconnects_per_participant: int = 100
    max_record_bytes_per_participant: int = 64 << 20
    max_record_bytes: int = 16 << 30

    def __post_init__(self) -> None:
        for key in (
            "joins_per_address_per_minute",
            "max_active_participants",
            "max_participants",
            "max_rounds_per_participant",
            "max_reconnects_per_participant",
        ):
            if not 1 <= getattr(self, key) <= MAX_LIMIT:
                raise ConfigError(f"limits.{key} must lie in [1, {MAX_LIMIT}], got {getattr(self, key)}")
        for key in ("max_record_bytes_per_participant", "max_record_bytes"):
            if not MIN_RECORD_BYTES <= getattr(self, key) <= MAX_RECORD_BYTES:
                raise ConfigError(
                    f"limits.{key} must lie in [{MIN_RECORD_BYTES:,}, {MAX_RECORD_BYTES:,}] bytes, got "
                    f"{getattr(self, key):,}"
                )
        if not 0.0 < self.idle_minutes <= 7 * 24 * 60:
            raise ConfigError(f"limits.idle_minutes must lie in (0, 10080] (a week), got {self.idle_minutes}")


@dataclass(frozen=True)
class StudyConfig:
    """A human-AI study (or a free-play page): flow, partners, kitchens, game settings, survey, storage.

    Attributes:
        name: the study's id: records go to `<storage.dir>/<name>/`; letters, digits, '_' and '-'.
        title: the page title.
        consent: consent text shown first ('' : no consent step). Paragraphs are separated by blank lines.
        instructions: instructions shown before the practice round (controls are listed below them).
        ask: information asked of each participant after consent (e.g. a Prolific id); nothing else
            about the person is recorded.
        levels: level specs; participant i plays all study rounds on `levels[i % len(levels)]`.
        partners: the partner conditions; each is played `rounds_per_partner` times.
        rounds_per_partner: study rounds per partner.
        shuffle_rounds: randomise the order of the rounds for each participant.
        practice: the practice round (null: none).
        mode: `turn_based` (the game advances on each key press, as NiceWebRL) or `real_time` (fixed
            ticks; the human's latest key is played at the next tick, else STAY).
        ticks_per_second: game speed in `real_time` mode.
        human_seat: the human's seat (0 blue, 1 red); -1: drawn at random for every round.
        agent_actions: `greedy` (the most likely action, as in the paper's study) or `sampled`.
        agent_gives_way_after: N > 0: once the agent's moves were cancelled by a collision N steps in a
            row, its next action is a move onto a free floor cell (the one its policy prefers), and so on
            while the collisions go on; 0 (the paper's agents): always its policy's action.
        env: the game's settings; the study round length is `env.max_steps`.
        survey: the post-round survey.
        completion_code: the code shown at the end ('' : a random code per participant).
        seed: seeds the participants' round orders, seat draws and partner draws (with their index).
        storage: where the records go.
        limits: bounds on joins (per client address, participants in progress, participants in all).
        free_play: play as a game, not a study: after each round the person plays again, with the same
            partner or the next one (their choice), for as long as they like; the page names the partner
            (policy and kind) and sums up their rounds; no completion code, no survey, no practice round.
    """

    name: str = ""  # required: `load_study` names a missing one (an empty file included)
    levels: tuple[str, ...] = ()
    partners: tuple[PartnerSpec, ...] = ()
    title: str = "Cooking together"
    consent: str = ""
    instructions: str = (
        "You and a partner run a kitchen together. Make onion soup: put three onions into a pot, wait "
        "while it cooks, take the soup out with a plate and bring it to the serving window (green). "
        "Each soup served earns 20 points for the team."
    )
    ask: tuple[InfoField, ...] = ()
    rounds_per_partner: int = 1
    shuffle_rounds: bool = True
    practice: PracticeConfig | None = None
    mode: str = "turn_based"
    ticks_per_second: float = 5.0
    human_seat: int = -1
    agent_actions: str = "greedy"
    agent_gives_way_after: int = 0
    env: EnvParams = field(default_factory=lambda: EnvParams(max_steps=200, random_start_facing=False))
    survey: SurveyConfig = field(default_factory=SurveyConfig)
    completion_code: str = ""
    seed: int = 0
    storage: StorageConfig = field(default_factory=StorageConfig)
    limits: LimitsConfig = field(default_factory=LimitsConfig)
    free_play: bool = False

    def __post_init__(self) -> None:
        missing = [key for key in ("name", "levels", "partners") if not getattr(self, key)]
        if len(missing) == 3:
            raise ConfigError(
                "a study needs at least `name`, `levels` and `partners` (see configs/study/default.yaml)"
            )
        if not self.name:
            raise ConfigError("the study has no `name` (1-64 letters, digits, '_' or '-'; records go there)")
        if not _NAME.match(self.name):
            raise ConfigError(f"study name {self.name!r} must be 1-64 letters, digits, '_' or '-'")
        safe_name(self.name, "study name", fix="name the study with 1-64 letters, digits, '_' or '-'")
        if not self.levels:
            raise ConfigError("levels is empty: list at least one level spec (e.g. counter_circuit)")
        if not self.partners:
            raise ConfigError("partners is empty: list at least one partner")
        names = [p.name for p in self.partners]
        if len(set(names)) != len(names):
            raise ConfigError(f"partner names must be unique, got {names}")
        if not 1 <= self.rounds_per_partner <= 100:
            raise ConfigError(f"rounds_per_partner must lie in [1, 100], got {self.rounds_per_partner}")
        if self.practice is not None and self.practice.partner and self.practice.partner not in names:
            raise ConfigError(
                f"practice.partner {self.practice.partner!r} is not one of the partners {names}"
            )
        if self.mode not in MODES:
            raise ConfigError(f"mode {self.mode!r} is unknown; choose one of {list(MODES)}")
        if not 0.0 < self.ticks_per_second <= MAX_TICKS_PER_SECOND:
            raise ConfigError(
                f"ticks_per_second must lie in (0, {MAX_TICKS_PER_SECOND:g}], got {self.ticks_per_second}"
            )
        if self.human_seat not in (-1, 0, 1):
            raise ConfigError(f"human_seat must be 0, 1 or -1 (random), got {self.human_seat}")
        if self.agent_actions not in AGENT_ACTIONS:
            raise ConfigError(
                f"agent_actions {self.agent_actions!r} is unknown; choose one of {list(AGENT_ACTIONS)}"
            )
        if not 0 <= self.agent_gives_way_after <= MAX_STEPS:
            raise ConfigError(
                f"agent_gives_way_after must lie in [0, {MAX_STEPS}] (0: the agent never steps aside), got "
                f"{self.agent_gives_way_after}"
            )
        if not 1 <= int(self.env.max_steps) <= MAX_STEPS:
            raise ConfigError(
                f"env.max_steps (the round length) must lie in [1, {MAX_STEPS}], got {self.env.max_steps}"
            )
        ids = [f.id for f in self.ask]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"ask ids must be unique, got {ids}")
        if len(self.completion_code) > 64 or not self.completion_code.isprintable():
            raise ConfigError("completion_code must be at most 64 printable characters")
        if self.free_play and (self.survey.items or self.practice is not None):
            raise ConfigError(
                "free_play: true plays rounds without a survey or a practice round: set "
                "`survey: {items: []}` and `practice: null`"
            )

    @property
    def num_rounds(self) -> int:
        """Study rounds per participant (the practice round not counted)."""
        return len(self.partners) * self.rounds_per_partner


def load_study(path: str | Path, overrides: tuple[str, ...] | list[str] = ()) -> tuple[StudyConfig, Path]:
    """Loads a study file (and `key=value` overrides); returns the config and the folder its paths are
    relative to. Raises `ConfigError` naming the problem."""
    p = Path(path)
    try:
        config = load_config(StudyConfig, p, list(overrides))
    except ConfigError as err:
        if str(p) in str(err):  # the reader's errors name the file already
            raise
        raise ConfigError(f"study file {str(p)!r}: {err}") from err
    return config, p.resolve().parent
