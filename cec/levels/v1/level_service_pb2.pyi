from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class LevelBatch(_message.Message):
    __slots__ = ("count", "grid", "agent_pos", "agent_dir", "size", "first_index", "names")
    COUNT_FIELD_NUMBER: _ClassVar[int]
    GRID_FIELD_NUMBER: _ClassVar[int]
    AGENT_POS_FIELD_NUMBER: _ClassVar[int]
    AGENT_DIR_FIELD_NUMBER: _ClassVar[int]
    SIZE_FIELD_NUMBER: _ClassVar[int]
    FIRST_INDEX_FIELD_NUMBER: _ClassVar[int]
    NAMES_FIELD_NUMBER: _ClassVar[int]
    count: int
    grid: bytes
    agent_pos: bytes
    agent_dir: bytes
    size: bytes
    first_index: int
    names: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, count: _Optional[int] = ..., grid: _Optional[bytes] = ..., agent_pos: _Optional[bytes] = ..., agent_dir: _Optional[bytes] = ..., size: _Optional[bytes] = ..., first_index: _Optional[int] = ..., names: _Optional[_Iterable[str]] = ...) -> None: ...

class GeneratorConfig(_message.Message):
    __slots__ = ("structures", "onion_piles", "plate_piles", "pots", "goals", "count_decay", "allow_decoys", "handover_share", "structure_weights")
    STRUCTURES_FIELD_NUMBER: _ClassVar[int]
    ONION_PILES_FIELD_NUMBER: _ClassVar[int]
    PLATE_PILES_FIELD_NUMBER: _ClassVar[int]
    POTS_FIELD_NUMBER: _ClassVar[int]
    GOALS_FIELD_NUMBER: _ClassVar[int]
    COUNT_DECAY_FIELD_NUMBER: _ClassVar[int]
    ALLOW_DECOYS_FIELD_NUMBER: _ClassVar[int]
    HANDOVER_SHARE_FIELD_NUMBER: _ClassVar[int]
    STRUCTURE_WEIGHTS_FIELD_NUMBER: _ClassVar[int]
    structures: _containers.RepeatedScalarFieldContainer[str]
    onion_piles: Bounds
    plate_piles: Bounds
    pots: Bounds
    goals: Bounds
    count_decay: float
    allow_decoys: bool
    handover_share: float
    structure_weights: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, structures: _Optional[_Iterable[str]] = ..., onion_piles: _Optional[_Union[Bounds, _Mapping]] = ..., plate_piles: _Optional[_Union[Bounds, _Mapping]] = ..., pots: _Optional[_Union[Bounds, _Mapping]] = ..., goals: _Optional[_Union[Bounds, _Mapping]] = ..., count_decay: _Optional[float] = ..., allow_decoys: _Optional[bool] = ..., handover_share: _Optional[float] = ..., structure_weights: _Optional[_Iterable[float]] = ...) -> None: ...

class Bounds(_message.Message):
    __slots__ = ("min", "max")
    MIN_FIELD_NUMBER: _ClassVar[int]
    MAX_FIELD_NUMBER: _ClassVar[int]
    min: int
    max: int
    def __init__(self, min: _Optional[int] = ..., max: _Optional[int] = ...) -> None: ...

class StreamLevelsRequest(_message.Message):
    __slots__ = ("seed", "batch_size", "count", "start_index", "config")
    SEED_FIELD_NUMBER: _ClassVar[int]
    BATCH_SIZE_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    START_INDEX_FIELD_NUMBER: _ClassVar[int]
    CONFIG_FIELD_NUMBER: _ClassVar[int]
    seed: int
    batch_size: int
    count: int
    start_index: int
    config: GeneratorConfig
    def __init__(self, seed: _Optional[int] = ..., batch_size: _Optional[int] = ..., count: _Optional[int] = ..., start_index: _Optional[int] = ..., config: _Optional[_Union[GeneratorConfig, _Mapping]] = ...) -> None: ...

class GetLevelsRequest(_message.Message):
    __slots__ = ("n", "seed", "start_index", "config")
    N_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    START_INDEX_FIELD_NUMBER: _ClassVar[int]
    CONFIG_FIELD_NUMBER: _ClassVar[int]
    n: int
    seed: int
    start_index: int
    config: GeneratorConfig
    def __init__(self, n: _Optional[int] = ..., seed: _Optional[int] = ..., start_index: _Optional[int] = ..., config: _Optional[_Union[GeneratorConfig, _Mapping]] = ...) -> None: ...

class GetHeldoutRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ValidateLevelRequest(_message.Message):
    __slots__ = ("packed", "ascii", "config")
    PACKED_FIELD_NUMBER: _ClassVar[int]
    ASCII_FIELD_NUMBER: _ClassVar[int]
    CONFIG_FIELD_NUMBER: _ClassVar[int]
    packed: LevelBatch
    ascii: str
    config: GeneratorConfig
    def __init__(self, packed: _Optional[_Union[LevelBatch, _Mapping]] = ..., ascii: _Optional[str] = ..., config: _Optional[_Union[GeneratorConfig, _Mapping]] = ...) -> None: ...

class ValidateLevelResponse(_message.Message):
    __slots__ = ("solvable", "reasons", "heldout", "heldout_name", "in_generator_space", "content_hash", "level")
    SOLVABLE_FIELD_NUMBER: _ClassVar[int]
    REASONS_FIELD_NUMBER: _ClassVar[int]
    HELDOUT_FIELD_NUMBER: _ClassVar[int]
    HELDOUT_NAME_FIELD_NUMBER: _ClassVar[int]
    IN_GENERATOR_SPACE_FIELD_NUMBER: _ClassVar[int]
    CONTENT_HASH_FIELD_NUMBER: _ClassVar[int]
    LEVEL_FIELD_NUMBER: _ClassVar[int]
    solvable: bool
    reasons: _containers.RepeatedScalarFieldContainer[str]
    heldout: bool
    heldout_name: str
    in_generator_space: bool
    content_hash: str
    level: LevelBatch
    def __init__(self, solvable: _Optional[bool] = ..., reasons: _Optional[_Iterable[str]] = ..., heldout: _Optional[bool] = ..., heldout_name: _Optional[str] = ..., in_generator_space: _Optional[bool] = ..., content_hash: _Optional[str] = ..., level: _Optional[_Union[LevelBatch, _Mapping]] = ...) -> None: ...

class ReportScoresRequest(_message.Message):
    __slots__ = ("levels", "scores")
    LEVELS_FIELD_NUMBER: _ClassVar[int]
    SCORES_FIELD_NUMBER: _ClassVar[int]
    levels: LevelBatch
    scores: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, levels: _Optional[_Union[LevelBatch, _Mapping]] = ..., scores: _Optional[_Iterable[float]] = ...) -> None: ...

class ReportScoresResponse(_message.Message):
    __slots__ = ("accepted", "buffer_size", "curriculum_enabled")
    ACCEPTED_FIELD_NUMBER: _ClassVar[int]
    BUFFER_SIZE_FIELD_NUMBER: _ClassVar[int]
    CURRICULUM_ENABLED_FIELD_NUMBER: _ClassVar[int]
    accepted: int
    buffer_size: int
    curriculum_enabled: bool
    def __init__(self, accepted: _Optional[int] = ..., buffer_size: _Optional[int] = ..., curriculum_enabled: _Optional[bool] = ...) -> None: ...

class GetServerInfoRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ServerInfo(_message.Message):
    __slots__ = ("version", "api_version", "generator", "layout_space_size", "heldout_count", "limits", "curriculum_enabled", "auth_required")
    VERSION_FIELD_NUMBER: _ClassVar[int]
    API_VERSION_FIELD_NUMBER: _ClassVar[int]
    GENERATOR_FIELD_NUMBER: _ClassVar[int]
    LAYOUT_SPACE_SIZE_FIELD_NUMBER: _ClassVar[int]
    HELDOUT_COUNT_FIELD_NUMBER: _ClassVar[int]
    LIMITS_FIELD_NUMBER: _ClassVar[int]
    CURRICULUM_ENABLED_FIELD_NUMBER: _ClassVar[int]
    AUTH_REQUIRED_FIELD_NUMBER: _ClassVar[int]
    version: str
    api_version: str
    generator: GeneratorConfig
    layout_space_size: str
    heldout_count: int
    limits: Limits
    curriculum_enabled: bool
    auth_required: bool
    def __init__(self, version: _Optional[str] = ..., api_version: _Optional[str] = ..., generator: _Optional[_Union[GeneratorConfig, _Mapping]] = ..., layout_space_size: _Optional[str] = ..., heldout_count: _Optional[int] = ..., limits: _Optional[_Union[Limits, _Mapping]] = ..., curriculum_enabled: _Optional[bool] = ..., auth_required: _Optional[bool] = ...) -> None: ...

class Limits(_message.Message):
    __slots__ = ("max_batch_size", "max_levels_per_request", "max_concurrent_streams", "max_distinct_configs")
    MAX_BATCH_SIZE_FIELD_NUMBER: _ClassVar[int]
    MAX_LEVELS_PER_REQUEST_FIELD_NUMBER: _ClassVar[int]
    MAX_CONCURRENT_STREAMS_FIELD_NUMBER: _ClassVar[int]
    MAX_DISTINCT_CONFIGS_FIELD_NUMBER: _ClassVar[int]
    max_batch_size: int
    max_levels_per_request: int
    max_concurrent_streams: int
    max_distinct_configs: int
    def __init__(self, max_batch_size: _Optional[int] = ..., max_levels_per_request: _Optional[int] = ..., max_concurrent_streams: _Optional[int] = ..., max_distinct_configs: _Optional[int] = ...) -> None: ...
