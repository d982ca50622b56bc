"""Policy bundles: a folder `cec zoo export` writes, loadable from disk or from an http(s) URL.

A bundle is self-describing:

    zoo.yaml       the manifest (`cec.agents.zoo`): one entry per policy, its checkpoint relative to the
                   folder and the SHA-256 of its parameters
    <name>/        each policy's checkpoint (`cec.agents.policy.save_policy`): `state.msgpack` (parameters
                   only) and `meta.json` (its training config, env steps, checksum)
    card.md        what the policies are, how they were trained, and their evaluation
    bundle.json    the index: format, every other file's size and SHA-256, the card's facts

`zoo_manifest(source)` turns what a user gives where a zoo is taken (`cec eval --zoo`, `cec play serve
--zoo`, a study's `zoo:`) into a manifest path: a folder stands for its `zoo.yaml` (its files checked
against `bundle.json` when it has one), an http(s) URL for the bundle published there, downloaded once
into the cache (`CEC_CACHE_DIR`, else `$XDG_CACHE_HOME/cec`, else `~/.cache/cec`) in bounded memory and
time: the index at most `INDEX_MAX_BYTES`, each file no larger than the index says and at most
`FILE_MAX_BYTES`, `BUNDLE_MAX_BYTES` in all, each file's SHA-256 checked before the bundle is used, every
checkpoint inside the bundle. A failed download leaves nothing in the cache. Anything else is a path, as
it was.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tempfile
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Mapping
from pathlib import Path, PurePosixPath
from typing import Any

from cec.config import ConfigError, read_user_bytes, read_user_yaml

#: The bundle's index, its format, and the manifest it holds.
INDEX, FORMAT, MANIFEST = "bundle.json", "cec-bundle/1", "zoo.yaml"
#: Bounds of a bundle read from a URL: its index, one file (a policy's parameters are a few MB), all of it.
INDEX_MAX_BYTES = 1 << 20
FILE_MAX_BYTES = 64 << 20
BUNDLE_MAX_BYTES = 512 << 20
#: The most files an index may list (a zoo has at most 512 policies of two files each).
FILES_MAX = 1100
#: Seconds a download may wait for the server before it is refused.
TIMEOUT_S = 30.0
_PART = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*")


class BundleError(ConfigError):
    """A bundle that cannot be used (unreachable, too large, not matching its index); names the cause."""


def is_url(source: str | Path) -> bool:
    return (
        isinstance(source, str) and source.split(":", 1)[0].lower() in ("http", "https") and "://" in source
    )


def cache_dir() -> Path:
    """Where downloaded bundles are kept: `CEC_CACHE_DIR`, else `$XDG_CACHE_HOME/cec`, else `~/.cache/cec`."""
    if os.environ.get("CEC_CACHE_DIR"):
        return Path(os.environ["CEC_CACHE_DIR"]) / "bundles"
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "cec" / "bundles"


def file_digest(path: Path) -> tuple[int, str]:
    """(size, SHA-256) of a file, read in chunks."""
    digest, size = hashlib.sha256(), 0
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
            size += len(chunk)
    return size, digest.hexdigest()


def parse_index(data: Any, where: str) -> dict[str, tuple[int, str]]:
    """The files an index lists, {relative path: (bytes, SHA-256)}; `BundleError` for anything else."""
    if not isinstance(data, Mapping) or data.get("format") != FORMAT:
        raise BundleError(f"{where}: not a bundle index (expected `format: {FORMAT}`)")
    files = data.get("files")
    if not isinstance(files, Mapping) or MANIFEST not in files or len(files) > FILES_MAX:
        raise BundleError(f"{where}: `files` must list {MANIFEST} and at most {FILES_MAX} files")
    out: dict[str, tuple[int, str]] = {}
    for name, item in files.items():
        parts = PurePosixPath(str(name)).parts
        if not parts or not all(_PART.fullmatch(p) for p in parts) or name == INDEX:
            raise BundleError(
                f"{where}: file name {str(name)[:80]!r} is not a plain relative path in the bundle"
            )
        size, sha = (item.get("bytes"), item.get("sha256")) if isinstance(item, Mapping) else (None, None)
        if isinstance(size, bool) or not isinstance(size, int) or not 0 <= size <= FILE_MAX_BYTES:
            raise BundleError(
                f"{where}: {name}: `bytes` must be a size of at most {FILE_MAX_BYTES:,} "
                f"({__name__}.FILE_MAX_BYTES), got {size!r}"
            )
        if not isinstance(sha, str) or not re.fullmatch(r"[0-9a-f]{64}", sha):
            raise BundleError(f"{where}: {name}: `sha256` must be 64 hex digits")
        out[str(name)] = (size, sha)
    total = sum(size for size, _ in out.values())
    if total > BUNDLE_MAX_BYTES:
        raise BundleError(
            f"{where}: {total:,} bytes in all, more than {BUNDLE_MAX_BYTES:,} ({__name__}.BUNDLE_MAX_BYTES)"
        )
    return out


def verify_folder(folder: Path, files: Mapping[str, tuple[int, str]]) -> None:
    """Every listed file of `folder` has its size and SHA-256; `BundleError` naming the first that does
    not."""
    for name, (size, sha) in files.items():
        path = folder / name
        if not path.is_file():
            raise BundleError(f"bundle {folder}: {name} is missing")
        if path.stat().st_size != size or file_digest(path) != (size, sha):
            raise BundleError(
                f"bundle {folder}: {name} does not match its SHA-256 in {INDEX}; it was changed"
            )
    _checkpoints_inside(folder)


def _checkpoints_inside(folder: Path) -> None:
    """A bundle's manifest names checkpoints inside the bundle only (never a file elsewhere on this disk)."""
    data = read_user_yaml(folder / MANIFEST, "zoo manifest", INDEX_MAX_BYTES, f"{__name__}.INDEX_MAX_BYTES")
    policies = data.get("policies") if isinstance(data, Mapping) else data
    root = folder.resolve()
    for item in policies if isinstance(policies, list) else []:
        checkpoint = item.get("checkpoint") if isinstance(item, Mapping) else None
        if isinstance(checkpoint, str) and not (folder / checkpoint).resolve().is_relative_to(root):
            raise BundleError(f"bundle {folder}: checkpoint {checkpoint[:80]!r} lies outside the bundle")


def _get(url: str, limit: int, what: str) -> bytes:
    """At most `limit` bytes from `url`; `BundleError` for a larger body, an error status or no answer."""
    try:
        with urllib.request.urlopen(url, timeout=TIMEOUT_S) as response:  # noqa: S310 (http(s) only: is_url)
            data = response.read(limit + 1)
    except urllib.error.HTTPError as err:
        raise BundleError(f"bundle {what}: {url} answered {err.code} {err.reason}") from None
    except (urllib.error.URLError, OSError, ValueError) as err:
        reason = getattr(err, "reason", err)
        raise BundleError(f"bundle {what}: {url} cannot be read: {reason}") from None
    if len(data) > limit:
        raise BundleError(f"bundle {what}: {url} is larger than {limit:,} bytes, the most read")
    return data


def fetch(url: str, into: Path | None = None) -> Path:
    """The folder of the bundle at `url` (its folder, or its `zoo.yaml` / `bundle.json`), downloaded into
    the cache once and checked file by file; a cached copy is checked again and used."""
    parsed = urllib.parse.urlsplit(url)
    path = parsed.path
    if path.endswith(f"/{MANIFEST}") or path.endswith(f"/{INDEX}"):
        path = path.rsplit("/", 1)[0]
    base = urllib.parse.urlunsplit(parsed._replace(path=path.rstrip("/") + "/", query="", fragment=""))
    raw = _get(base + INDEX, INDEX_MAX_BYTES, "index")
    try:
        index = json.loads(raw)
    except (ValueError, RecursionError):
        raise BundleError(f"bundle index {base + INDEX} is not JSON") from None
    files = parse_index(index, base + INDEX)
    folder = (into or cache_dir()) / hashlib.sha256(raw).hexdigest()[:32]
    if folder.is_dir():
        verify_folder(folder, files)
        return folder
    folder.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=".fetch-", dir=folder.parent))
    try:
        for name, (size, sha) in files.items():
            data = _get(base + urllib.parse.quote(name), size, name)
            if len(data) != size or hashlib.sha256(data).hexdigest() != sha:
                raise BundleError(f"bundle {base}: {name} does not match its size and SHA-256 in {INDEX}")
            (work / name).parent.mkdir(parents=True, exist_ok=True)
            (work / name).write_bytes(data)
        (work / INDEX).write_bytes(raw)
        _checkpoints_inside(work)
        try:
            work.rename(folder)
        except OSError:  # another process fetched the same bundle meanwhile: use its copy
            shutil.rmtree(work, ignore_errors=True)
            verify_folder(folder, files)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    return folder


def zoo_manifest(source: str | Path) -> Path:
    """The manifest a zoo source stands for: an http(s) URL's bundle (fetched), a folder's `zoo.yaml`
    (checked against its `bundle.json` if it has one), else the path as given."""
    if is_url(source):
        return fetch(str(source)) / MANIFEST
    path = Path(source)
    if path.is_dir():
        if (path / INDEX).is_file():
            where = str(path / INDEX)
            raw = read_user_bytes(
                path / INDEX, "bundle index", INDEX_MAX_BYTES, f"{__name__}.INDEX_MAX_BYTES"
            )
            try:
                index = json.loads(raw)
            except (ValueError, RecursionError):
                raise BundleError(f"bundle index {where} is not JSON") from None
            verify_folder(path, parse_index(index, where))
        return path / MANIFEST
    return path
