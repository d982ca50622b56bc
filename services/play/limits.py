"""Bounds on what anonymous clients of `cec play` can make the server do: a per-key rate limiter (token
buckets) for joins, and a JSON parser that refuses what the study never sends (deep nesting, huge numbers,
NaN) with a message instead of a traceback.
"""

from __future__ import annotations

import json
import math
import re
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

#: Deepest nesting of arrays/objects a client's JSON may have (the page sends at most 2 levels).
MAX_JSON_DEPTH = 16
#: Longest number literal a client's JSON may have (a browser's doubles take at most ~25 characters).
MAX_NUMBER_CHARS = 64

_STRING = re.compile(r'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)
_BRACKET = re.compile(r"[\[\]{}]")


class JSONInputError(ValueError):
    """A client's JSON is malformed or exceeds the bounds above; the message says which."""


def json_depth(text: str) -> int:
    """The deepest nesting of `[`/`{` in JSON text (brackets inside strings not counted), without
    parsing it (so without recursion)."""
    depth = deepest = 0
    for m in _BRACKET.finditer(_STRING.sub("", text)):
        if m.group() in "[{":
            depth += 1
            deepest = max(deepest, depth)
        else:
            depth -= 1
    return deepest


def _number(kind: Callable[[str], Any]) -> Callable[[str], Any]:
    def parse(literal: str) -> Any:
        if len(literal) > MAX_NUMBER_CHARS:
            raise JSONInputError(f"a number of {len(literal)} characters (at most {MAX_NUMBER_CHARS})")
        return kind(literal)

    return parse


def _constant(name: str) -> Any:
    raise JSONInputError(f"{name} is not a JSON number")


def parse_json(data: str | bytes) -> Any:
    """Strict JSON (UTF-8 when bytes): at most `MAX_JSON_DEPTH` levels, numbers of at most
    `MAX_NUMBER_CHARS` characters, no NaN/Infinity. `JSONInputError` naming the problem otherwise."""
    try:
        text = data.decode("utf-8") if isinstance(data, bytes) else data
    except UnicodeDecodeError as err:
        raise JSONInputError(f"not UTF-8 text ({err.reason} at byte {err.start})") from None
    depth = json_depth(text)
    if depth > MAX_JSON_DEPTH:
        raise JSONInputError(f"nested {depth} levels deep (at most {MAX_JSON_DEPTH})")
    try:
        return json.loads(text, parse_int=_number(int), parse_float=_number(float), parse_constant=_constant)
    except json.JSONDecodeError as err:
        raise JSONInputError(f"not JSON ({err.msg} at line {err.lineno} column {err.colno})") from None
    except (ValueError, RecursionError) as err:  # JSONInputError from the hooks; never expected otherwise
        raise JSONInputError(str(err)) from None


def brief(value: Any, limit: int = 40) -> str:
    """`repr(value)` cut to `limit` characters: what an error message may echo of a client's input."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


class RateLimiter:
    """A token bucket per key (e.g. a client address): `burst` tokens at once, refilled at `per_minute`.

    Keys whose bucket has filled up again are forgotten, and at most `max_keys` are kept (the least
    recently used forgotten first), so the table stays bounded however many keys clients bring.
    """

    def __init__(
        self,
        per_minute: float,
        burst: int,
        *,
        max_keys: int = 65_536,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if per_minute <= 0 or burst < 1:
            raise ValueError("a rate limiter needs per_minute > 0 and burst >= 1")
        self.rate = per_minute / 60.0
        self.burst = float(burst)
        self.max_keys = max_keys
        self.clock = clock
        self._buckets: OrderedDict[str, tuple[float, float]] = OrderedDict()  # key -> (tokens, at)

    def _tokens(self, key: str, now: float) -> float:
        tokens, at = self._buckets.get(key, (self.burst, now))
        return min(self.burst, tokens + (now - at) * self.rate)

    def take(self, key: str) -> float:
        """Takes a token of `key`: 0.0 if there was one, else the seconds until there will be one."""
        now = self.clock()
        while self._buckets:  # forget the oldest buckets that are full again
            oldest = next(iter(self._buckets))
            if self._tokens(oldest, now) < self.burst and len(self._buckets) < self.max_keys:
                break
            del self._buckets[oldest]
        tokens = self._tokens(key, now)
        if tokens < 1.0:
            self._buckets[key] = (tokens, now)
            self._buckets.move_to_end(key)
            return max(math.ceil((1.0 - tokens) / self.rate * 1000) / 1000, 0.001)
        self._buckets[key] = (tokens - 1.0, now)
        self._buckets.move_to_end(key)
        return 0.0

    def __len__(self) -> int:
        return len(self._buckets)


__all__ = ["MAX_JSON_DEPTH", "MAX_NUMBER_CHARS", "JSONInputError", "RateLimiter", "brief", "parse_json"]
