"""Names that become paths: the one gate between a name a user gave (a zoo entry, `--prefix`, a run name)
and a file or folder the code writes.

    out = named_path(out_dir, prefix + policy.name, "exported policy name", fix="rename the entry")

A name is one plain path component: not empty, no path separator or NUL, not `.` or `..`, no control
characters, not hidden (a leading `.`: `.git`, a run's `.lock`), not a temporary name of the writers here
(`*.tmp`), not a Windows device name, at most `NAME_MAX_BYTES` bytes. So a written path stays inside the
folder it is joined to: a manifest entry named `../victim` or `/home/me` is refused before anything is
written or removed.
"""

from __future__ import annotations

from pathlib import Path

from cec.config import ConfigError

#: The longest name, in UTF-8 bytes (what Linux and macOS file systems allow in one component).
NAME_MAX_BYTES = 255
#: Names Windows reserves for devices (in any case, with any extension), refused everywhere so that a
#: folder written here can be copied there.
RESERVED_NAMES = frozenset(
    ["con", "prn", "aux", "nul"] + [f"com{i}" for i in range(1, 10)] + [f"lpt{i}" for i in range(1, 10)]
)
#: The suffix of the temporary files and folders the writers here rename into place.
TEMP_SUFFIX = ".tmp"


class UnsafeNameError(ConfigError):
    """A name that would not stay one component of the folder it is joined to."""


def name_problem(name: object) -> str | None:
    """Why `name` cannot be a file or folder name, or None when it can."""
    if not isinstance(name, str) or not name:
        return "it is empty" if name == "" else f"it is a {type(name).__name__}, not a string"
    if "/" in name or "\\" in name:
        return "it holds a path separator ('/' or '\\'): a name must not reach another folder"
    if name in (".", ".."):
        return f"{name!r} names a folder itself, not an entry in it"
    if any(ord(c) < 32 or ord(c) == 127 for c in name):
        return "it holds a control character (a line break, a tab or NUL)"
    if name.startswith("."):
        return "it starts with '.' (a hidden name, such as a run's .lock)"
    if name.endswith(TEMP_SUFFIX):
        return f"it ends with {TEMP_SUFFIX!r}, the suffix of the writers' temporary files"
    if name.split(".")[0].strip().lower() in RESERVED_NAMES:
        return f"{name.split('.')[0]!r} is a reserved device name on Windows"
    if len(name.encode("utf-8", errors="surrogatepass")) > NAME_MAX_BYTES:
        return f"it is longer than {NAME_MAX_BYTES} bytes ({__name__}.NAME_MAX_BYTES)"
    return None


def safe_name(
    name: object, what: str, *, fix: str = "choose a plain name (letters, digits, '_', '-')"
) -> str:
    """`name` when it is one plain path component (module docstring), else `UnsafeNameError` naming
    `what`, the name, the cause and `fix`."""
    problem = name_problem(name)
    if problem is not None:
        raise UnsafeNameError(f"{what} {str(name)[:300]!r} cannot be a file or folder name: {problem}; {fix}")
    assert isinstance(name, str)
    return name


def named_path(folder: str | Path, name: object, what: str, *, fix: str = "") -> Path:
    """`folder / name`, the name checked by `safe_name` (so the path stays inside `folder`)."""
    checked = safe_name(name, what, fix=fix) if fix else safe_name(name, what)
    return Path(folder) / checked
