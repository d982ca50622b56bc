"""`RedisClient`: one Redis connection pool for a `StoreConfig` and the translation of redis-py's errors into
`StoreError`s that name the URL and the fix. The control plane, its consumer group and the study's records
(`services.play.recording`) all reach Redis through it."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import redis
from redis.backoff import ExponentialBackoff
from redis.retry import Retry

from services.store.config import (
    ENV_PASSWORD,
    ENV_URL,
    INSTALL_HINT,
    MIN_REDIS_VERSION,
    StoreConfig,
    StoreError,
    StoreKeyTypeError,
    StoreUnavailableError,
)

T = TypeVar("T")


def _redis_version(info: Mapping[str, Any]) -> tuple[int, ...]:
    try:
        return tuple(int(x) for x in str(info.get("redis_version", "0")).split(".")[:2])
    except ValueError:
        return (0,)


class RedisClient:
    """A redis-py client for `config`: connect and socket timeouts, retries with exponential backoff, the
    password from the config, the URL or the environment (in that order). `redis` is the redis-py client;
    `call` runs commands on it with its errors translated (`StoreUnavailableError` when Redis cannot be
    reached). Thread-safe (one connection pool).

    Args:
        config: where Redis is and how to reach it.
        decode_responses: replies as `str` (True) or `bytes`.
        fix: what to set to point at another Redis, for the messages (default: the store url).
    """

    def __init__(self, config: StoreConfig, *, decode_responses: bool = True, fix: str = "") -> None:
        self.config = c = config
        self.fix = fix or f"set the store url or {ENV_URL}=redis://host:port/db"
        try:
            pool = redis.ConnectionPool.from_url(
                c.resolved_url,
                decode_responses=decode_responses,
                protocol=2,
                socket_connect_timeout=c.connect_timeout_s,
                socket_timeout=c.socket_timeout_s,
                retry=Retry(ExponentialBackoff(cap=c.retry_backoff_max_s, base=c.retry_backoff_s), c.retries),
                retry_on_error=[redis.ConnectionError, redis.TimeoutError],
            )
        except ValueError as err:
            raise StoreError(
                f"Redis URL {c.display_url!r} is malformed ({err}); use redis://host:port/db ({self.fix})"
            ) from err
        # The URL's own password wins inside redis-py; the documented order is config, URL, environment.
        pool.connection_kwargs["password"] = c.resolved_password or None
        # redis-py annotates results as `T | Awaitable[T]` (one API for sync and async); this client is sync.
        self.redis: Any = redis.Redis(connection_pool=pool)

    def close(self) -> None:
        self.redis.close()
        self.redis.connection_pool.disconnect()

    def key(self, *parts: str) -> str:
        """`<prefix>:<part>:<part>...`: a key under the configured prefix."""
        return ":".join((self.config.key_prefix, *parts))

    def unreachable(self, err: BaseException) -> StoreUnavailableError:
        return StoreUnavailableError(
            f"cannot reach Redis at {self.config.display_url} ({err}). Start a Redis server there "
            f"(`redis-server`; {INSTALL_HINT}), or point at a running one: {self.fix}"
        )

    def auth_failed(self, err: BaseException) -> StoreError:
        return StoreError(
            f"Redis at {self.config.display_url} refused the credentials ({err}). Set the password that "
            f"matches its `requirepass` with the store password or {ENV_PASSWORD} (or none if it has none)"
        )

    def call(self, what: str, fn: Callable[[], T]) -> T:
        """Runs `fn` (Redis commands), translating redis-py errors into `StoreError`s naming `what` failed
        (`StoreUnavailableError`: Redis cannot be reached; `StoreKeyTypeError`: a key holds another type)."""
        try:
            return fn()
        except (redis.AuthenticationError, redis.exceptions.NoPermissionError) as err:
            raise self.auth_failed(err) from err
        except (redis.ConnectionError, redis.TimeoutError) as err:
            raise self.unreachable(err) from err
        except redis.ResponseError as err:
            if str(err).startswith(("NOAUTH", "WRONGPASS")):
                raise self.auth_failed(err) from err
            if str(err).startswith("WRONGTYPE"):
                raise StoreKeyTypeError(
                    f"Redis at {self.config.display_url} failed to {what}: {err}"
                ) from err
            raise StoreError(f"Redis at {self.config.display_url} failed to {what}: {err}") from err
        except redis.RedisError as err:
            raise StoreError(f"Redis at {self.config.display_url} failed to {what}: {err}") from err

    def check(self) -> str:
        """Pings Redis and checks its version; returns the version. `StoreError` naming the fix otherwise."""
        self.call("answer PING", self.redis.ping)
        info = self.call("report its version", lambda: self.redis.info("server"))
        version = _redis_version(info)
        if version < MIN_REDIS_VERSION:
            raise StoreError(
                f"Redis at {self.config.display_url} is version {info.get('redis_version')}; this project "
                f"needs >= {'.'.join(map(str, MIN_REDIS_VERSION))} (streams with XPENDING IDLE). "
                f"Upgrade it; {INSTALL_HINT}"
            )
        return str(info.get("redis_version", ""))

    def ping(self) -> bool:
        """True if Redis answers now (never raises)."""
        try:
            return bool(self.redis.ping())
        except redis.RedisError:
            return False
