"""Checkpoints in a safe format: msgpack state (flax.serialization, never pickle), JSON metadata, SHA-256.

A checkpoint is a directory `<run>/checkpoints/update_<N>/` holding

    state.msgpack   the training state pytree (params, optimizer state, RNG keys, env and LSTM carries, ...)
    meta.json       {"format", "sha256", "size", "update", "env_steps", "milestone", "config", "metadata"}

It is written to a temporary directory and renamed into place, so a crash never leaves a half-written
checkpoint under its final name. Loading reads the state in bounded memory: a file whose size is not the one
its metadata records (`size`; checkpoints written before it recorded one are hashed in chunks first), or
larger than `STATE_MAX_BYTES`, is refused before it is read, so a damaged checkpoint costs no more memory
than a good one. It checks the checksum (corruption), then every leaf's shape and
dtype against the caller's template (a checkpoint of another network or batch size), and refuses with a
`CheckpointError` that says what is wrong and what to do.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import shutil
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO, TypeVar

import jax
import numpy as np
from flax import serialization

from cec.config import ConfigError, open_user_file, read_user_file

FORMAT = "cec-checkpoint/1"
STATE_FILE = "state.msgpack"
META_FILE = "meta.json"
#: In a checkpoint's metadata: why it is a record (its metadata: update, SHA-256, config) without its state
#: (a finished run carried to another machine once its games were played). Such a checkpoint lists and
#: counts as any other; loading it fails with the reason.
RECORD_ONLY = "record_only"
#: The largest checkpoint metadata read (`save` writes a few kB: the run's config and metadata).
META_MAX_BYTES = 16 << 20
#: The largest checkpoint state read (the paper's network with Adam's moments for four seeds is ~50 MB); the
#: environment's `CEC_CHECKPOINT_MAX_BYTES` raises it.
STATE_MAX_BYTES = 4 << 30
#: The bytes hashed at a time when a checkpoint without a recorded size is checked before it is read.
HASH_CHUNK_BYTES = 1 << 20

T = TypeVar("T")


class CheckpointError(RuntimeError):
    """A checkpoint is missing, corrupt or does not match what the caller expects."""


class CorruptCheckpointError(CheckpointError):
    """A checkpoint's files are damaged (missing, unreadable, checksum or metadata wrong): an older one of
    the same run may still be good, unlike a checkpoint that does not fit the caller's state."""


class RunBusyError(CheckpointError):
    """Another process is training the run (it holds the run directory's lock)."""


LOCK_FILE = ".lock"


class RunLock:
    """An exclusive, non-blocking lock on a run directory (`<run>/.lock`, flock), so two processes never
    train the same run at once. The kernel drops it when the holder exits, however it exits, so a killed
    trainer leaves no stale lock. The file holds the holder's pid, for messages."""

    def __init__(self, run_dir: str | Path) -> None:
        self.path = Path(run_dir) / LOCK_FILE
        self._fd: int | None = None

    def acquire(self) -> RunLock:
        """Takes the lock, creating the run directory; `RunBusyError` when another process holds it,
        `ConfigError` naming the folder when it cannot be created or written (checked before any work)."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            raise ConfigError(
                f"run directory {str(self.path.parent)!r} cannot be created or written "
                f"({err.strerror or err}); give run_dir= a folder you can write (the run goes in "
                "<run_dir>/<name>)"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise RunBusyError(
                f"{self.path.parent} is being trained by another process (pid {holder}); wait for it to "
                f"finish, or stop it (it saves a checkpoint) and resume"
            ) from None
        with contextlib.suppress(OSError):  # the pid is for messages only: a full disk keeps the lock
            os.ftruncate(fd, 0)
            os.pwrite(fd, str(os.getpid()).encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, 0)
            os.close(self._fd)  # closing drops the flock
            self._fd = None

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def code_version(*, short: bool = False) -> str:
    """The git commit of the code, `+dirty` when tracked files have uncommitted changes (the one revision
    helper: checkpoints, the level server, reports and benchmarks). In a copy without its `.git` (a lent
    GPU machine gets the tree alone): `$CEC_GIT_REV` as the sender set it, else `unknown`."""
    root = Path(__file__).resolve().parent.parent

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", *args], cwd=root, capture_output=True, text=True, timeout=5, check=True
        ).stdout.strip()

    try:
        rev = git("rev-parse", *(["--short"] if short else []), "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return os.environ.get("CEC_GIT_REV") or "unknown"
    return rev + ("+dirty" if dirty else "")


def save(
    path: str | Path,
    state: Any,
    *,
    update: int,
    env_steps: int,
    config: dict,
    metadata: dict,
    milestone: bool = False,
) -> Path:
    """Writes `state` (a pytree of arrays) and its metadata to the checkpoint directory `path`, atomically.
    An existing checkpoint there is replaced; any other folder there is refused (`CheckpointError`), never
    removed."""
    path = Path(path)
    data = serialization.to_bytes(jax.device_get(state))
    meta = {
        "format": FORMAT,
        "sha256": hashlib.sha256(data).hexdigest(),
        "size": len(data),
        "update": int(update),
        "env_steps": int(env_steps),
        "milestone": bool(milestone),
        "config": config,
        "metadata": metadata,
    }
    tmp = path.with_name(path.name + ".tmp")
    _check_replaceable(path)  # before any write: a folder that is not a checkpoint is never removed
    _check_replaceable(tmp)
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        tmp.mkdir(parents=True)
        (tmp / STATE_FILE).write_bytes(data)
        (tmp / META_FILE).write_text(json.dumps(meta, indent=2, sort_keys=True))
        for f in (tmp / STATE_FILE, tmp / META_FILE):
            with open(f, "rb") as fh:
                os.fsync(fh.fileno())
    except OSError as err:  # a full disk: nothing of it stays, the checkpoints before it are untouched
        shutil.rmtree(tmp, ignore_errors=True)
        raise CheckpointError(
            f"cannot write checkpoint {path} ({err.strerror or err}); nothing of it was kept and the "
            "checkpoints before it are as they were. Free space and resume the run"
        ) from None
    if path.exists():
        shutil.rmtree(path)
    tmp.rename(path)
    return path


def _check_replaceable(path: Path) -> None:
    """`CheckpointError` unless `path` is absent, an empty folder, or a folder holding nothing but a
    checkpoint's files (`save` replaces it): anything else there is not ours to remove."""
    if not os.path.lexists(path):
        return
    if path.is_symlink() or not path.is_dir():
        found = "a link" if path.is_symlink() else "a file"
        raise CheckpointError(
            f"{path} is {found}, not a checkpoint folder; nothing was written or removed. Move it away or "
            "write the checkpoint under another name"
        )
    entries = {p.name for p in path.iterdir()}
    if entries - {STATE_FILE, META_FILE} or (entries and META_FILE not in entries and path.suffix != ".tmp"):
        shown = ", ".join(sorted(entries)[:5]) + (", ..." if len(entries) > 5 else "")
        raise CheckpointError(
            f"{path} exists and is not a checkpoint (it holds {shown}); nothing was written or removed. "
            "Move it away or write the checkpoint under another name"
        )


def read_meta(path: str | Path) -> dict:
    """The metadata of the checkpoint at `path` (no state loaded)."""
    meta_file = Path(path) / META_FILE
    if not meta_file.exists():
        raise CorruptCheckpointError(f"{path} is not a checkpoint: {META_FILE} is missing")
    setting = f"{__name__}.META_MAX_BYTES"
    text = read_user_file(
        meta_file, "checkpoint metadata", META_MAX_BYTES, setting, error=CorruptCheckpointError
    )
    try:
        meta: dict = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as err:
        cause = "nested too deeply" if isinstance(err, RecursionError) else str(err)[:200]
        raise CorruptCheckpointError(
            f"checkpoint metadata {meta_file} is corrupt ({cause}); use another checkpoint"
        ) from None
    if not isinstance(meta, dict):
        raise CorruptCheckpointError(
            f"checkpoint metadata {meta_file} is not a JSON object; use another checkpoint"
        )
    if meta.get("format") != FORMAT:
        raise CheckpointError(f"{path} has format {str(meta.get('format'))[:80]!r}, expected {FORMAT!r}")
    problem = _meta_problem(meta)
    if problem:
        raise CorruptCheckpointError(
            f"checkpoint metadata {meta_file} is corrupt: {problem}; use another checkpoint"
        )
    return meta


MAX_COUNT = 10**15  # no run takes this many updates or env steps: a larger count is corruption


def _meta_problem(meta: dict) -> str | None:
    """What is wrong with the fields `save` writes, or None."""
    digest = meta.get("sha256")
    if not isinstance(digest, str) or len(digest) != 64 or any(c not in "0123456789abcdef" for c in digest):
        return f"sha256 must be 64 lowercase hex digits, got {str(digest)[:80]!r}"
    for key in ("update", "env_steps", *(("size",) if "size" in meta else ())):
        value = meta.get(key)
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_COUNT:
            return f"{key} must be an integer in [0, {MAX_COUNT}], got {str(value)[:80]!r}"
    if not isinstance(meta.get("milestone"), bool):
        return f"milestone must be true or false, got {str(meta.get('milestone'))[:80]!r}"
    for key in ("config", "metadata"):
        if not isinstance(meta.get(key), dict):
            return f"{key} must be a JSON object, got {type(meta.get(key)).__name__}"
    return None


def load(path: str | Path, template: T, *, part: str | None = None) -> tuple[T, dict]:
    """Loads the state at `path` into the structure of `template` and returns (state, meta).

    `part` loads one top-level field of the stored state only (e.g. `"params"` of a training state, for
    which `template` is then the parameters' structure); the whole file's checksum is still verified.
    Raises `CheckpointError` if the files are missing, the checksum does not match (corruption or
    tampering), or the stored tree does not have `template`'s structure, shapes and dtypes.
    """
    path = Path(path)
    meta = read_meta(path)
    data = _read_state(path, meta)
    try:
        raw = serialization.msgpack_restore(data)
        if part is not None:
            if not isinstance(raw, dict) or part not in raw:
                raise CheckpointError(f"checkpoint {path} holds no {part!r} (not a training state?)")
            raw = raw[part]
        state = serialization.from_state_dict(template, raw)
    except (ValueError, KeyError, TypeError) as err:
        raise CheckpointError(
            f"checkpoint {path} does not match the expected state structure: {err}"
        ) from err
    _check_leaves(path, template, state)
    _check_finite(path, state if part == "params" or not hasattr(state, "params") else state.params)
    return state, meta


def state_max_bytes() -> int:
    """`STATE_MAX_BYTES`, or the environment's `CEC_CHECKPOINT_MAX_BYTES` where set (`CheckpointError` when
    that is not a positive integer)."""
    text = os.environ.get("CEC_CHECKPOINT_MAX_BYTES")
    if text is None:
        return STATE_MAX_BYTES
    value = int(text) if text.strip().isdigit() else 0
    if value <= 0:
        raise CheckpointError(f"CEC_CHECKPOINT_MAX_BYTES must be a positive integer, got {text[:40]!r}")
    return value


def _read_state(path: Path, meta: dict) -> bytes:
    """The bytes of the checkpoint's state, in bounded memory: refused (`CorruptCheckpointError`) before they
    are read when the file's size is not the recorded one or is over `state_max_bytes()`; a checkpoint that
    records no size (written before it did) is hashed in chunks first; the bytes read are checked against the
    recorded SHA-256."""
    state_file = path / STATE_FILE
    if not state_file.exists():
        why = meta.get("metadata", {}).get(RECORD_ONLY)
        if why:  # its metadata kept on purpose, its state left behind
            raise CorruptCheckpointError(f"checkpoint {path} is a record without its {STATE_FILE}: {why}")
        raise CorruptCheckpointError(f"checkpoint {path} has no {STATE_FILE}")
    limit = state_max_bytes()
    with open_user_file(state_file, "checkpoint state", error=CorruptCheckpointError) as f:
        size = os.fstat(f.fileno()).st_size
        recorded = meta.get("size")
        if recorded is not None and size != recorded:
            raise CorruptCheckpointError(
                f"checkpoint {path} is corrupt: {STATE_FILE} holds {size:,} bytes, its metadata says "
                f"{recorded:,}; it was not read. Resume from an earlier checkpoint or delete this one"
            )
        if size > limit:
            raise CorruptCheckpointError(
                f"checkpoint {path}: {STATE_FILE} holds {size:,} bytes, more than {limit:,}, the most read "
                f"({__name__}.STATE_MAX_BYTES); it was not read. If it is genuine, raise the cap: "
                "CEC_CHECKPOINT_MAX_BYTES=N in the environment"
            )
        try:
            if recorded is None:  # nothing says how large it should be: its checksum first, in chunks
                hasher = hashlib.sha256()
                while chunk := f.read(HASH_CHUNK_BYTES):
                    hasher.update(chunk)
                _check_digest(path, hasher.hexdigest(), meta)
                f.seek(0)
            data = f.read(size + 1)
        except OSError as err:
            raise CorruptCheckpointError(
                f"checkpoint {path}: {STATE_FILE} cannot be read ({err.strerror or err}); use another "
                "checkpoint"
            ) from None
    if len(data) != size:
        raise CorruptCheckpointError(
            f"checkpoint {path}: {STATE_FILE} changed while it was read; load it again"
        )
    _check_digest(path, hashlib.sha256(data).hexdigest(), meta)
    return data


def _check_digest(path: Path, digest: str, meta: dict) -> None:
    if digest != meta["sha256"]:
        raise CorruptCheckpointError(
            f"checkpoint {path} is corrupt: {STATE_FILE} has SHA-256 {digest[:12]}..., its metadata says "
            f"{meta['sha256'][:12]}...; it was not loaded. "
            "Resume from an earlier checkpoint or delete this one"
        )


def _check_finite(path: Path, params: Any) -> None:
    """`CorruptCheckpointError` when a floating-point parameter is NaN or infinite: a diverged run's state
    (its checksum fine) that would play or train as garbage; an older checkpoint of the run may be good."""
    for key_path, leaf in jax.tree_util.tree_flatten_with_path(params)[0]:
        arr = np.asarray(leaf)
        if np.issubdtype(arr.dtype, np.floating) and not np.isfinite(arr).all():
            bad = int(np.size(arr) - np.isfinite(arr).sum())
            raise CorruptCheckpointError(
                f"checkpoint {path} holds non-finite parameters ({bad} of {arr.size} values of "
                f"{jax.tree_util.keystr(key_path)} are NaN or infinite: the run diverged before it was "
                "saved); it was not loaded. Use an earlier checkpoint of the run"
            )


def _check_leaves(path: Path, template: Any, state: Any) -> None:
    want = jax.tree_util.tree_flatten_with_path(template)[0]
    got = jax.tree.leaves(state)
    if len(want) != len(got):
        raise CheckpointError(f"checkpoint {path} has {len(got)} arrays, expected {len(want)}")
    for (key_path, w), g in zip(want, got, strict=True):
        w_shape, g_shape = tuple(np.shape(w)), tuple(np.shape(g))
        w_dtype, g_dtype = np.dtype(w.dtype), np.asarray(g).dtype
        if w_shape != g_shape or w_dtype != g_dtype:
            name = jax.tree_util.keystr(key_path)
            raise CheckpointError(
                f"checkpoint {path} does not fit this run: {name} is {g_dtype}{list(g_shape)} in the "
                f"checkpoint but {w_dtype}{list(w_shape)} here "
                "(different network, batch size or number of seeds?)"
            )


@dataclass(frozen=True)
class CheckpointInfo:
    path: Path
    update: int
    milestone: bool


class CheckpointStore:
    """The checkpoints of one run: `<run_dir>/checkpoints/update_<N>/`, keep-last-N plus milestones."""

    def __init__(self, run_dir: str | Path, keep_last: int) -> None:
        self.root = Path(run_dir) / "checkpoints"
        self.keep_last = keep_last

    def path(self, update: int) -> Path:
        return self.root / f"update_{update:09d}"

    def directories(self) -> list[Path]:
        """Every checkpoint directory, readable or not, oldest first (not the temporary directories of
        interrupted writes)."""
        return sorted(p for p in self.root.glob("update_*") if not p.name.endswith(".tmp"))

    def list(self) -> list[CheckpointInfo]:
        """Checkpoints with valid metadata, oldest first."""
        out = []
        for p in self.directories():
            try:
                meta = read_meta(p)
            except CheckpointError:
                continue
            out.append(CheckpointInfo(p, int(meta["update"]), bool(meta["milestone"])))
        return sorted(out, key=lambda c: c.update)

    def latest(self) -> CheckpointInfo | None:
        items = self.list()
        return items[-1] if items else None

    def load_latest(
        self, template: T, log: TextIO, problem: Callable[[dict], str | None] = lambda meta: None
    ) -> tuple[T, dict] | None:
        """(state, meta) of the newest checkpoint that loads into `template`, or None if there is none.

        A damaged checkpoint (`CorruptCheckpointError`, or metadata in which `problem` finds something
        wrong: a count the run cannot have reached) is passed over for the next older one with a warning on
        `log` naming it and why, and left in place; one that does not fit `template` stops the search (an
        older one of the same run would not fit either).
        """
        skipped = []
        for path in reversed(self.directories()):
            try:
                wrong = problem(read_meta(path))
                if wrong:
                    raise CorruptCheckpointError(
                        f"checkpoint metadata {path / META_FILE} is corrupt: {wrong}"
                    )
                return load(path, template)
            except CorruptCheckpointError as err:
                print(f"warning: passing over a damaged checkpoint: {err}", file=log, flush=True)
                skipped.append(path.name)
        if skipped:
            raise CorruptCheckpointError(
                f"no checkpoint of {self.root.parent} can be loaded (damaged: {', '.join(skipped)}); "
                "restore them from a copy, or start a new run under another name"
            )
        return None

    def save(
        self, state: Any, *, update: int, env_steps: int, config: dict, metadata: dict, milestone: bool
    ) -> Path:
        """Writes a checkpoint, then deletes non-milestone ones beyond the newest `keep_last`."""
        path = save(
            self.path(update),
            state,
            update=update,
            env_steps=env_steps,
            config=config,
            metadata=metadata,
            milestone=milestone,
        )
        regular = [c for c in self.list() if not c.milestone]
        for old in regular[: max(0, len(regular) - self.keep_last)]:
            shutil.rmtree(old.path, ignore_errors=True)
        return path
