"""Typed configuration of the level server (YAML preset: configs/level_server.yaml; `key=value` overrides)."""

from __future__ import annotations

import ipaddress
import os
import ssl
from dataclasses import dataclass, field
from pathlib import Path

from cec.config import ConfigError, read_user_bytes
from cec.levels.generator import GeneratorConfig
from services.ports import LEVEL_SERVER_GRPC_PORT, METRICS_PORTS, check_distinct, check_port

TOKEN_ENV = "CEC_LEVEL_SERVER_TOKEN"
#: the most bytes a request without levels can need (a generator config is under 200): larger `GetLevels`,
#: `StreamLevels`, `GetHeldout` and `GetServerInfo` requests get RESOURCE_EXHAUSTED before they are parsed
SMALL_REQUEST_BYTES = 16 * 1024
#: the longest ASCII kitchen: 9 rows of 9 tiles and a facing line, with room for blank lines and CRs
MIN_ASCII_BYTES = 128


@dataclass(frozen=True)
class CurriculumConfig:
    """Prioritized level replay over levels whose learning scores consumers report (`ReportScores`).

    Attributes:
        enabled: off by default: streams and `GetLevels` then return only fresh generated levels, a pure
            function of (seed, config, index). When on, a share of every reply is replayed levels.
        replay_prob: share of each reply drawn from the replay buffer once it holds `min_fill` levels.
        capacity: levels kept in the buffer; a new level replaces the lowest-scored one when it scores higher.
        min_fill: buffer size before any level is replayed.
        temperature: rank prioritisation P(i) ~ (1 / rank_i) ** (1 / temperature).
        staleness_coef: weight of the staleness term (levels not sampled for long get picked again).
        seed: seed of the replay sampler.
        served_window: how many of the levels most recently served (generated or replayed) the server
            remembers (8 bytes each). `ReportScores` takes scores only for levels among them, so no client
            can put a level the server did not produce (a held-out or unsolvable kitchen, any hand-made one)
            into what it streams; report scores before more than this many levels have been served since.
    """

    enabled: bool = False
    replay_prob: float = 0.5
    capacity: int = 4000
    min_fill: int = 100
    temperature: float = 0.3
    staleness_coef: float = 0.3
    seed: int = 0
    served_window: int = 2**20

    def __post_init__(self) -> None:
        if not 0.0 <= self.replay_prob <= 1.0:
            raise ConfigError(f"curriculum.replay_prob must lie in [0, 1], got {self.replay_prob}")
        if not 1 <= self.min_fill <= self.capacity:
            raise ConfigError(
                f"curriculum needs 1 <= min_fill <= capacity, got min_fill={self.min_fill}, "
                f"capacity={self.capacity}"
            )
        if self.temperature <= 0:
            raise ConfigError(f"curriculum.temperature must be > 0, got {self.temperature}")
        if not 0.0 <= self.staleness_coef <= 1.0:
            raise ConfigError(f"curriculum.staleness_coef must lie in [0, 1], got {self.staleness_coef}")
        if self.served_window < 1:
            raise ConfigError(
                f"curriculum.served_window must be >= 1 (levels remembered for ReportScores), got "
                f"{self.served_window}; the default is {2**20}"
            )


def check_token(token: str, source: str) -> None:
    """`ConfigError` naming `source` (the setting or variable the token came from) unless the token is
    printable ASCII, the only text gRPC metadata carries."""
    if token and not (token.isascii() and token.isprintable()):
        raise ConfigError(
            f"{source} must be printable ASCII (gRPC metadata cannot carry newlines, control or non-ASCII "
            "characters: no client could ever authenticate); choose another token"
        )


@dataclass(frozen=True)
class LevelServerConfig:
    """The level server.

    Attributes:
        host: bind address. Loopback by default; any other address requires `auth_token` and TLS
            (`tls_cert` + `tls_key`) unless `insecure` is set.
        port: gRPC port (0: pick a free one; the chosen port is logged).
        metrics_port: Prometheus `/metrics` HTTP port on `metrics_host` (0: pick a free one, -1: off).
        metrics_host: bind address of the metrics endpoint.
        auth_token: clients must send `authorization: Bearer <token>` metadata (health checks are exempt).
            Empty: read it from the environment variable CEC_LEVEL_SERVER_TOKEN; unset there too: no auth.
        tls_cert: PEM certificate chain file; with `tls_key`, the server only speaks TLS.
        tls_key: PEM private key file.
        insecure: allow a non-loopback bind without TLS and token (a trusted private network only).
        seed: seed of the server's own sequence (`GetLevels` without a seed); -1: random at start-up.
        chunk_levels: levels generated per compiled call and cached together. Part of the sequence
            definition: level i of a seed is level i % chunk of chunk i // chunk, so servers agree on a
            sequence only with the same value.
        cache_chunks: generated chunks kept (LRU) for replays of a sequence and small requests.
        workers: threads generating levels off the event loop.
        max_batch_size: largest `StreamLevels` batch.
        max_levels_per_request: largest `GetLevels` count (and `ReportScores` batch); streams are unlimited.
        max_concurrent_streams: streams served at once; more get RESOURCE_EXHAUSTED.
        max_distinct_configs: generator configs compiled at most (each costs compile time and memory).
        max_message_bytes: largest request message accepted (gRPC answers RESOURCE_EXHAUSTED beyond it):
            it bounds `ReportScores` batches (~94 bytes a level: ~11,000 levels at the default 1 MiB); the
            other requests are bounded tighter, by what they can need (`SMALL_REQUEST_BYTES`, and
            `max_ascii_bytes` for `ValidateLevel`).
        max_ascii_bytes: largest ASCII kitchen `ValidateLevel` parses (a 9x9 kitchen with its facing line is
            about 100 bytes); longer text gets INVALID_ARGUMENT before any parsing.
        max_concurrent_validations: `ValidateLevel` and `ReportScores` calls checked at once, on their own
            threads (apart from the generation `workers`, so validations never starve generation); more
            get RESOURCE_EXHAUSTED.
        max_concurrent_rpcs: calls of any kind (streams included) in progress at once; more get
            RESOURCE_EXHAUSTED from gRPC. With `max_message_bytes` it bounds the memory requests can hold.
        grace_seconds: on SIGTERM, time given to in-flight RPCs before they are cancelled.
        generator: defaults for request fields left unset (and the only config when requests set none).
        curriculum: prioritized level replay (off by default).
    """

    host: str = "127.0.0.1"
    port: int = LEVEL_SERVER_GRPC_PORT
    metrics_port: int = METRICS_PORTS["level_server"]
    metrics_host: str = "127.0.0.1"
    auth_token: str = ""
    tls_cert: str = ""
    tls_key: str = ""
    insecure: bool = False
    seed: int = -1
    chunk_levels: int = 512
    cache_chunks: int = 256
    workers: int = 2
    max_batch_size: int = 4096
    max_levels_per_request: int = 100_000
    max_concurrent_streams: int = 32
    max_distinct_configs: int = 8
    max_message_bytes: int = 1024 * 1024
    max_ascii_bytes: int = 4096
    max_concurrent_validations: int = 4
    max_concurrent_rpcs: int = 128
    grace_seconds: float = 5.0
    generator: GeneratorConfig = field(default_factory=GeneratorConfig)
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)

    def __post_init__(self) -> None:
        check_port("port", self.port)
        check_port("metrics_port", self.metrics_port, off=True)
        check_distinct(
            [
                ("port", "the level server's gRPC", self.port),
                ("metrics_port", "its metrics", self.metrics_port),
            ]
        )
        for name in ("chunk_levels", "cache_chunks", "workers", "max_batch_size", "max_levels_per_request",
                     "max_concurrent_streams", "max_distinct_configs", "max_message_bytes", "max_ascii_bytes",
                     "max_concurrent_validations", "max_concurrent_rpcs"):  # fmt: skip
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.max_message_bytes < SMALL_REQUEST_BYTES:
            raise ConfigError(
                f"max_message_bytes must be >= {SMALL_REQUEST_BYTES} (what a request with a generator config "
                f"may need), got {self.max_message_bytes}; the default is {1024 * 1024}"
            )
        if self.max_ascii_bytes < MIN_ASCII_BYTES:
            raise ConfigError(
                f"max_ascii_bytes must be >= {MIN_ASCII_BYTES} (a 9x9 kitchen with its facing line), got "
                f"{self.max_ascii_bytes}; the default is 4096"
            )
        if self.max_concurrent_rpcs <= self.max_concurrent_streams:
            raise ConfigError(
                f"max_concurrent_rpcs ({self.max_concurrent_rpcs}) must exceed max_concurrent_streams "
                f"({self.max_concurrent_streams}), or open streams would leave no room for other calls; "
                "raise max_concurrent_rpcs or lower max_concurrent_streams"
            )
        if not self.generator.exclude_heldout:
            raise ConfigError(
                "generator.exclude_heldout=false cannot be honoured: a level server never streams the "
                "validation or test kitchens (they are the held-out evaluation sets); remove the setting"
            )
        check_token(self.auth_token, "auth_token")
        check_token(os.environ.get(TOKEN_ENV, ""), f"the {TOKEN_ENV} environment variable")
        if bool(self.tls_cert) != bool(self.tls_key):
            raise ConfigError("TLS needs both tls_cert and tls_key (PEM files); set both or neither")
        if self.tls_cert:
            check_tls_pair(self.tls_cert, self.tls_key)
        if not self.is_loopback and not self.insecure and not (self.tls and self.token):
            raise ConfigError(
                f"binding {self.host!r} exposes the server beyond this machine: set auth_token (or "
                f"{TOKEN_ENV}) and tls_cert/tls_key, or set insecure=true on a trusted private network"
            )

    @property
    def token(self) -> str:
        """The bearer token clients must present ('' = no authentication)."""
        return self.auth_token or os.environ.get(TOKEN_ENV, "")

    @property
    def tls(self) -> bool:
        return bool(self.tls_cert)

    @property
    def is_loopback(self) -> bool:
        return is_loopback_host(self.host)

    def exposure_warning(self) -> str | None:
        """What an `insecure` bind beyond this machine leaves open (logged at start), or None."""
        if self.is_loopback or self.tls:
            return None
        if self.token:
            return (
                f"{self.host} is reachable beyond this machine without TLS: the bearer token crosses the "
                "network in clear text, readable on its way; set tls_cert/tls_key"
            )
        return f"{self.host} is reachable beyond this machine without TLS or token: anyone there may call it"


def is_loopback_host(host: str) -> bool:
    """Whether `host` (a name or an IP address, IPv6 in brackets or not) is this machine's loopback: only
    `localhost` and loopback addresses count, never a name that would need resolving."""
    host = host.strip().strip("[]")
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def is_loopback_address(address: str) -> bool:
    """Whether a gRPC target (`host:port`, `[v6]:port`, `dns:///host:port`, `ipv4:...`, `unix:path`) reaches
    only this machine (a Unix socket does)."""
    target = address.strip()
    if target.startswith(("unix:", "unix-abstract:")):
        return True
    for scheme in ("dns:///", "dns:", "ipv4:", "ipv6:"):
        if target.startswith(scheme):
            target = target[len(scheme) :]
            break
    if target.startswith("[") and "]" in target:
        return is_loopback_host(target[1 : target.index("]")])
    host = target.rpartition(":")[0] if target.count(":") == 1 else target
    return is_loopback_host(host)


#: The largest PEM file read (a certificate chain or key is a few kB, a CA bundle a few hundred).
PEM_MAX_BYTES = 1 << 20


def read_pem(path: str, what: str) -> bytes:
    """The bytes of a PEM file (a certificate or key), or a `ConfigError` naming `what` and the cause:
    missing, not a regular file (a FIFO would hang the start, a device never end), larger than
    `PEM_MAX_BYTES`, or not PEM at all (gRPC would fail later, with a less helpful message)."""
    data = read_user_bytes(Path(path), f"{what} file", PEM_MAX_BYTES, f"{__name__}.PEM_MAX_BYTES")
    if b"-----BEGIN " not in data:
        raise ConfigError(
            f"{what} file {path!r} is not PEM (no '-----BEGIN' line); give the PEM file, e.g. as written by "
            "`openssl req -x509 -newkey rsa:2048 -nodes -keyout key.pem -out cert.pem`"
        )
    return data


def check_tls_pair(cert: str, key: str) -> None:
    """`ConfigError` unless `cert` and `key` are PEM files holding a certificate chain and its unencrypted
    private key (checked with Python's own TLS library: gRPC would only say it could not bind)."""
    read_pem(cert, "tls_cert")
    read_pem(key, "tls_key")
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    try:
        context.load_cert_chain(cert, key, password=lambda: b"")  # an encrypted key fails, never prompts
    except ssl.SSLError as err:
        raise ConfigError(
            f"tls_cert {cert!r} and tls_key {key!r} are not a certificate and its unencrypted private key "
            f"({err.reason or err}); give the pair the certificate was made with"
        ) from None
