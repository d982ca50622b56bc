"""Where the control plane lives: `StoreConfig` (URL, password, timeouts, retries, consumer-group limits),
`redact_url`, the environment variables read, and the errors every store operation raises."""

from __future__ import annotations

import os
from dataclasses import dataclass
from urllib.parse import urlsplit, urlunsplit

from cec.config import ConfigError

ENV_URL = "CEC_REDIS_URL"
ENV_PASSWORD = "CEC_REDIS_PASSWORD"
DEFAULT_URL = "redis://127.0.0.1:6379/0"
MIN_REDIS_VERSION = (6, 2)  # XPENDING IDLE, SMISMEMBER
INSTALL_HINT = (
    "to install it: `sudo apt-get install redis-server` (Debian/Ubuntu), `brew install redis` (macOS)"
)


class StoreError(RuntimeError):
    """The control plane cannot do what was asked; the message names the cause and the fix."""


class StoreUnavailableError(StoreError):
    """Redis cannot be reached (down, restarting, wrong address or a network failure)."""


class StoreKeyTypeError(StoreError):
    """A Redis key holds another type than the command needs (someone else's data under the key prefix)."""


# --- configuration -----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StoreConfig:
    """Where the control plane lives and how hard to try reaching it.

    Attributes:
        url: `redis://[:password@]host:port/db` (or `rediss://` for TLS, `unix:///path.sock`). Empty: the
            environment variable CEC_REDIS_URL, else redis://127.0.0.1:6379/0. (`cec up` starts its own
            Redis when neither is given.)
        password: Redis password (`requirepass`). Empty: a password in the URL, else the environment
            variable CEC_REDIS_PASSWORD, else none. Prefer the environment variable over a config file.
        key_prefix: prefix of every key (`<prefix>:runs`, ...); separate deployments may share one Redis.
        connect_timeout_s: time allowed to open a connection.
        socket_timeout_s: time allowed for one command's reply (blocking reads are kept below it).
        retries: retries of a command after a connection error or timeout, with exponential backoff.
        retry_backoff_s: first backoff between retries (doubled each retry).
        retry_backoff_max_s: longest backoff between retries.
        claim_idle_s: a checkpoint event delivered to a consumer and not acknowledged for this long is
            handed to another consumer of the group (its consumer is presumed dead). Consumers that work
            longer on one event call `CheckpointConsumer.touch` to keep it.
        max_deliveries: an event delivered this many times without an acknowledgement is given up on
            (moved to `<prefix>:dead:<group>`), so one poison event cannot stall a group forever.
    """

    url: str = ""
    password: str = ""
    key_prefix: str = "cec"
    connect_timeout_s: float = 2.0
    socket_timeout_s: float = 5.0
    retries: int = 3
    retry_backoff_s: float = 0.05
    retry_backoff_max_s: float = 1.0
    claim_idle_s: float = 600.0
    max_deliveries: int = 5

    def __post_init__(self) -> None:
        if self.url and urlsplit(self.url).scheme not in ("redis", "rediss", "unix"):
            raise ConfigError(
                f"store url {self.url!r} must start with redis://, rediss:// or unix:// (e.g. {DEFAULT_URL})"
            )
        if not self.key_prefix or any(c.isspace() for c in self.key_prefix) or self.key_prefix.endswith(":"):
            raise ConfigError(
                f"store key_prefix {self.key_prefix!r} must be non-empty, without spaces or a trailing ':'"
            )
        for name in ("connect_timeout_s", "socket_timeout_s", "claim_idle_s"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"store {name} must be > 0, got {getattr(self, name)}")
        if self.retries < 0 or self.retry_backoff_s < 0 or self.retry_backoff_max_s < 0:
            raise ConfigError("store retries, retry_backoff_s and retry_backoff_max_s must be >= 0")
        if self.max_deliveries < 1:
            raise ConfigError(f"store max_deliveries must be >= 1, got {self.max_deliveries}")

    @property
    def url_given(self) -> bool:
        """Whether a URL was set (here or in CEC_REDIS_URL) rather than left to the default."""
        return bool(self.url or os.environ.get(ENV_URL))

    @property
    def resolved_url(self) -> str:
        """The URL used: `url`, else CEC_REDIS_URL, else the default."""
        return self.url or os.environ.get(ENV_URL) or DEFAULT_URL

    @property
    def resolved_password(self) -> str:
        """The password used ('' = none): `password`, else the URL's, else CEC_REDIS_PASSWORD."""
        return self.password or urlsplit(self.resolved_url).password or os.environ.get(ENV_PASSWORD, "")

    @property
    def display_url(self) -> str:
        """The URL with any password masked, for messages and logs."""
        return redact_url(self.resolved_url)


def redact_url(url: str) -> str:
    """`url` with the password (if any) replaced by `***`."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    netloc = parts.netloc.rsplit("@", 1)
    user = parts.username or ""
    return urlunsplit(parts._replace(netloc=f"{user}:***@{netloc[-1]}"))
