"""Typed, frozen configuration: load dataclasses from YAML presets and `key=value` overrides, strictly.

Unknown keys, wrong types and malformed overrides raise `ConfigError` naming the key, the expected type
and the fix, before any work starts. Nothing is silently dropped or coerced: an int is accepted for a float
field, and so is exponent notation without a dot (`lr: 3e-4`, which YAML 1.1 reads as a string); nothing
else converts.

    params = load_config(EnvParams, "configs/env/cec_train.yaml", overrides=["max_steps=256"])

A config file may be an overlay: `base: <file>` names the file it builds on (relative to the overlay's folder,
else to the repository; chains allowed), and the overlay gives only what differs. Mappings merge key by key,
anything else (a number, a string, a list) replaces the base's value; the merged mapping is then checked as
one file is, so an unknown key in any file of the chain is refused.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import os
import re
import stat
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO, TypeVar

import yaml

T = TypeVar("T")

# `3e-4`, `-1E5`: numbers to a reader, strings to YAML 1.1 (its float pattern needs a dot).
_EXPONENT_FLOAT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


class ConfigError(ValueError):
    """A configuration file or override is invalid; the message names the key and the fix."""


def from_dict(cls: type[T], data: Mapping[str, Any], *, where: str = "") -> T:
    """Builds dataclass `cls` from `data`, checking every key and value type (recursively)."""
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where or cls.__name__}: expected a mapping of fields, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        path = f"{where}.{key}" if where else str(key)
        if key not in names:
            close = difflib.get_close_matches(str(key), names, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ConfigError(f"unknown key {path!r} for {cls.__name__}{hint} Valid keys: {', '.join(names)}")
        kwargs[key] = _check_value(hints[key], value, path)
    if not where:
        return cls(**kwargs)
    try:
        return cls(**kwargs)
    except ConfigError as err:  # a nested config's own check: say where it is nested
        raise ConfigError(f"{where}: {err}") from None


def _check_value(kind: Any, value: Any, path: str) -> Any:
    args = typing.get_args(kind)
    if type(None) in args and len(args) == 2:  # Optional[X]: null or an X
        return (
            None if value is None else _check_value(next(a for a in args if a is not type(None)), value, path)
        )
    if dataclasses.is_dataclass(kind) and isinstance(kind, type):
        return from_dict(kind, value, where=path)
    if kind is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{path} must be true or false, got {value!r}")
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{path} must be an integer, got {value!r}")
        return value
    if kind is float:
        if isinstance(value, str) and _EXPONENT_FLOAT.fullmatch(value.strip()):
            value = float(value)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{path} must be a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{path} must be a finite number, got {value!r}")
        return float(value)
    if kind is str:
        if not isinstance(value, str):
            raise ConfigError(f"{path} must be a string, got {value!r}")
        return value
    if typing.get_origin(kind) is tuple:
        args = typing.get_args(kind)
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{path} must be a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_check_value(args[0], v, f"{path}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{path} must be a list of {len(args)} values, got {value!r}")
        return tuple(
            _check_value(a, v, f"{path}[{i}]") for i, (a, v) in enumerate(zip(args, value, strict=True))
        )
    return value  # other annotations (arrays, unions) are checked by the dataclass itself


def apply_overrides(data: Mapping[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    """Returns a copy of `data` with `a.b=value` overrides applied (values parsed as YAML scalars)."""
    out: dict[str, Any] = {k: v for k, v in data.items()}
    for item in overrides:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"override {item!r} is not of the form key=value (e.g. max_steps=256)")
        parts = key.strip().split(".")
        node = out
        for part in parts[:-1]:
            child = node.get(part)
            node[part] = dict(child) if isinstance(child, Mapping) else {}
            node = node[part]
        try:
            node[parts[-1]] = yaml.safe_load(raw) if raw.strip() else ""
        except yaml.YAMLError as err:
            raise ConfigError(
                f"override {item!r}: the value is not valid YAML ({err.__class__.__name__}); quote it or fix "
                "the brackets (lists are written [1, 2])"
            ) from err
        except RecursionError:  # as a file that nests too deeply (`load_config`)
            raise ConfigError(
                f"override {key.strip()[:200]}=...: the value nests too deeply to be read ({len(raw):,} "
                "characters); a config value nests a few levels at most"
            ) from None
    return out


class _UniqueKeyLoader(yaml.SafeLoader):
    """YAML's safe loader, refusing a key given twice in one mapping (plain YAML keeps the last one)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise ConfigError(
                    f"key {key!r} is given twice (line {key_node.start_mark.line + 1}); keep one of them"
                )
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


#: The largest config file read (a config is a few kB; more is a mistake or an attack).
CONFIG_MAX_BYTES = 1 << 20


def open_user_file(path: Path, kind: str, *, error: type[Exception] = ConfigError) -> BinaryIO:
    """`path` opened for reading if it is a regular file (not a folder, FIFO, socket or device, which could
    block or never end), else `error` naming the file, its kind and the cause. Opened without blocking and
    checked on the open file, so a FIFO swapped in after a check cannot hang the reader."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise error(f"{kind} {str(path)!r} does not exist") from None
    except IsADirectoryError:
        raise error(f"{kind} {str(path)!r} is a folder; give the file inside it") from None
    except OSError as err:
        raise error(f"{kind} {str(path)!r} cannot be read: {err.strerror or err}") from None
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise error(f"{kind} {str(path)!r} is a folder; give the file inside it")
        if not stat.S_ISREG(mode):
            raise error(f"{kind} {str(path)!r} is not a regular file (a FIFO, socket or device); give a file")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_user_bytes(
    path: Path, kind: str, max_bytes: int, setting: str, *, error: type[Exception] = ConfigError
) -> bytes:
    """The bytes of a file a user or a run folder gave, read in bounded memory and time: a regular file only
    (`open_user_file`) of at most `max_bytes`; `error` naming the file, its kind, the cause and, for a file
    too large, the cap and its `setting` (the constant or key that holds it) otherwise."""
    with open_user_file(path, kind, error=error) as f:
        try:
            data = f.read(max_bytes + 1)
        except OSError as err:
            raise error(f"{kind} {str(path)!r} cannot be read: {err.strerror or err}") from None
    if len(data) > max_bytes:
        raise error(
            f"{kind} {str(path)!r} is larger than {max_bytes:,} bytes, the most read ({setting}); give the "
            "right file"
        )
    return data


def read_user_file(
    path: Path,
    kind: str,
    max_bytes: int,
    setting: str = "cec.config.CONFIG_MAX_BYTES",
    *,
    error: type[Exception] = ConfigError,
) -> str:
    """The UTF-8 text of a file a user or a run folder gave (`read_user_bytes`)."""
    data = read_user_bytes(path, kind, max_bytes, setting, error=error)
    try:
        return data.decode()
    except UnicodeDecodeError as err:
        raise error(f"{kind} {str(path)!r} is not UTF-8 text: {err}") from None


def read_user_json(
    path: Path, kind: str, max_bytes: int, setting: str, *, error: type[Exception] = ConfigError
) -> Any:
    """The JSON value of a file a user or a run folder gave (`read_user_bytes`); `error` naming the file
    when it is not JSON, nests too deeply to parse, or holds NaN/Infinity (not JSON)."""
    text = read_user_file(path, kind, max_bytes, setting, error=error)
    try:
        return json.loads(text, parse_constant=_no_constant)
    except (json.JSONDecodeError, _NonFiniteJSONError) as err:
        raise error(f"{kind} {str(path)!r} is not valid JSON: {err}") from None
    except RecursionError:
        raise error(f"{kind} {str(path)!r} nests too deeply to be read") from None


class _NonFiniteJSONError(ValueError):
    """NaN or Infinity in a file read as JSON (Python's reader takes them; JSON has no such numbers)."""


def _no_constant(name: str) -> Any:
    raise _NonFiniteJSONError(f"{name} is not a JSON number")


def read_user_yaml(
    path: Path, kind: str, max_bytes: int, setting: str, *, error: type[Exception] = ConfigError
) -> Any:
    """The YAML value (safe loader) of a file a user or a run folder gave (`read_user_bytes`); `error`
    naming the file when it is not YAML or nests too deeply to parse."""
    text = read_user_file(path, kind, max_bytes, setting, error=error)
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise error(f"{kind} {str(path)!r} is not valid YAML: {err}") from None
    except RecursionError:
        raise error(f"{kind} {str(path)!r} nests too deeply to be read") from None


#: The most files in one `base:` chain (an overlay of an overlay of a preset is two; more is a mistake).
BASE_CHAIN_MAX = 16

#: The repository's root: a `base:` path that is not in the overlay's folder is looked up from here.
REPO_ROOT = Path(__file__).resolve().parents[1]


def _read_config_mapping(p: Path) -> dict[str, Any]:
    """The top-level mapping of one config file (its `base:` key included), strictly read."""
    text = read_user_file(p, "config file", CONFIG_MAX_BYTES, "cec.config.CONFIG_MAX_BYTES")
    try:
        data = yaml.load(text, Loader=_UniqueKeyLoader) or {}  # noqa: S506 (a safe loader)
    except yaml.YAMLError as err:
        raise ConfigError(f"config file {str(p)!r} is not valid YAML: {err}") from err
    except ConfigError as err:
        raise ConfigError(f"config file {str(p)!r}: {err}") from err
    except RecursionError as err:
        raise ConfigError(f"config file {str(p)!r} nests too deeply to be a config") from err
    if not isinstance(data, Mapping):
        raise ConfigError(f"config file {str(p)!r} must hold a mapping of fields at the top level")
    return dict(data)


def _base_path(base: Any, overlay: Path) -> Path:
    """The file an overlay's `base:` names: absolute, else in the overlay's folder, else in the repository."""
    if not isinstance(base, str) or not base.strip():
        raise ConfigError(
            f"config file {str(overlay)!r}: base must be the path of the config file it overlays, "
            f"got {base!r}"
        )
    given = Path(base.strip()).expanduser()
    candidates = [given] if given.is_absolute() else [overlay.parent / given, REPO_ROOT / given]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    looked = " and ".join(str(c) for c in candidates)
    raise ConfigError(
        f"config file {str(overlay)!r}: its base {base!r} does not exist (looked at {looked}); give the "
        "base's path relative to this file's folder or to the repository"
    )


def _merge(base: Mapping[str, Any], overlay: Mapping[str, Any]) -> dict[str, Any]:
    """`base` with `overlay` on top: mappings merge key by key, any other value replaces the base's."""
    out = dict(base)
    for key, value in overlay.items():
        below = out.get(key)
        out[key] = (
            _merge(below, value) if isinstance(value, Mapping) and isinstance(below, Mapping) else value
        )
    return out


def read_config(path: str | Path) -> dict[str, Any]:
    """The mapping of a config file with its `base:` chain merged under it (the base first, each overlay on
    top); `ConfigError` naming the file for a missing base, a chain that loops or runs past `BASE_CHAIN_MAX`
    files, or any file that is not a config."""
    chain: list[Path] = []
    layers: list[dict[str, Any]] = []
    p = Path(path)
    while True:
        here = p.resolve()
        if here in chain:
            loop = " -> ".join(str(c) for c in [*chain[chain.index(here) :], here])
            raise ConfigError(
                f"config file {str(p)!r}: its base chain loops ({loop}); remove the `base:` that closes it"
            )
        if len(chain) == BASE_CHAIN_MAX:
            raise ConfigError(
                f"config file {str(path)!r}: its base chain is longer than {BASE_CHAIN_MAX} files "
                "(cec.config.BASE_CHAIN_MAX); base the overlay on a file nearer the root"
            )
        chain.append(here)
        data = _read_config_mapping(p)
        has_base = "base" in data
        base = data.pop("base", None)
        layers.append(data)
        if not has_base:
            break
        p = _base_path(base, p)
    merged: dict[str, Any] = {}
    for layer in reversed(layers):
        merged = _merge(merged, layer)
    return merged


def load_config(cls: type[T], path: str | Path | None = None, overrides: Sequence[str] = ()) -> T:
    """Loads `cls` from a YAML file and its `base:` chain (or `cls`'s defaults when `path` is None), then
    applies overrides."""
    data = read_config(path) if path is not None else {}
    return from_dict(cls, apply_overrides(data, overrides))
