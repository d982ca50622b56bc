"""Overcooked kitchens by name, file or folder: the one resolver every command that names levels uses.

A level spec is a comma-separated list of tokens, each one of

    heldout            the held-out evaluation set (5 classic + 100 generated kitchens)
    classic            the 5 classic kitchens;  cramped_room, ... one of them
    generated          the 100 held-out generated kitchens;  generated_000 .. generated_099 one of them
    path/to/file.txt   an ASCII kitchen file (`cec.levels.ascii`), named by its stem
    path/to/folder/    every `*.txt` kitchen file in the folder, sorted by name

Relative paths are taken from `base_dir` (the working directory unless given). Files are read with a size
bound, parsed and checked for solvability here, so a malformed or unsolvable kitchen is refused with its
reason (a `ConfigError` naming the file) before anything is compiled for it.
"""

from __future__ import annotations

from pathlib import Path

from cec.config import ConfigError
from cec.levels.ascii import from_ascii
from cec.levels.classic import CLASSIC_ASCII, classic_level
from cec.levels.level import Level, LevelError

MAX_KITCHEN_FILE_BYTES = 64 * 1024
KITCHEN_SUFFIX = ".txt"
SET_NAMES = ("heldout", "classic", "generated")


def is_path_spec(token: str) -> bool:
    """Whether a level token names a file or folder rather than a built-in kitchen or set."""
    return "/" in token or "\\" in token or token.endswith(KITCHEN_SUFFIX) or token.startswith((".", "~"))


def _tokens(spec: str) -> list[str]:
    return [t.strip() for t in spec.split(",") if t.strip()]


def _names_path(token: str) -> bool:
    return is_path_spec(token) or Path(token).exists()


def names_files(spec: str) -> bool:
    """Whether a level spec names any kitchen file or folder (relative paths from the working directory)."""
    return any(_names_path(t) for t in _tokens(spec))


def absolute_paths(spec: str) -> str:
    """The spec with its file and folder tokens made absolute (from the working directory)."""
    return ",".join(str(Path(t).expanduser().absolute()) if _names_path(t) else t for t in _tokens(spec))


def read_kitchen(path: Path) -> Level:
    """An ASCII kitchen file, parsed; `LevelError` naming the file if it is unreadable, binary, oversized or
    malformed (solvability is not checked here: see `validate_solvable`)."""
    try:
        if (size := path.stat().st_size) > MAX_KITCHEN_FILE_BYTES:
            raise LevelError(
                f"{path} is {size:,} bytes; an ASCII kitchen is a few lines of tiles "
                f"(at most {MAX_KITCHEN_FILE_BYTES:,} bytes here)"
            )
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise LevelError(f"{path} is not a text file; an ASCII kitchen is UTF-8 lines of tiles") from None
    except OSError as err:
        raise LevelError(f"cannot read {path}: {err.strerror}") from None
    try:
        return from_ascii(text)
    except LevelError as err:
        raise LevelError(f"{path}: {err}") from None


def kitchen_files(path: Path) -> list[Path]:
    """The kitchen files a path names: itself, or a folder's `*.txt` files in name order."""
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix == KITCHEN_SUFFIX and p.is_file())
        if not files:
            raise ConfigError(f"folder {str(path)!r} has no {KITCHEN_SUFFIX} kitchen files")
        return files
    if path.is_file():
        return [path]
    raise ConfigError(f"no kitchen file or folder {str(path)!r}")


def load_kitchens(path: Path, allow_decoys: bool = False) -> dict[str, Level]:
    """{stem: level} of the solvable kitchen files at `path` (a file or a folder); `ConfigError` naming the
    first file that is malformed or unsolvable, with the reasons."""
    from cec.levels.solvability import validate_solvable

    out: dict[str, Level] = {}
    for file in kitchen_files(path):
        try:
            level = read_kitchen(file)
        except LevelError as err:
            raise ConfigError(f"kitchen file {err}") from None
        problems = validate_solvable(level, allow_decoys)
        if problems:
            raise ConfigError(f"kitchen file {file} is not solvable: " + "; ".join(problems))
        out[file.stem] = level
    return out


def resolve_levels(spec: str, base_dir: Path | None = None) -> dict[str, Level]:
    """{name: level} for a level spec (see the module docstring), in the order the tokens name them;
    `ConfigError` naming the bad token or file."""
    from cec.levels.heldout import heldout_levels

    tokens = _tokens(spec)
    if not tokens:
        raise ConfigError("levels is empty; give e.g. `heldout`, `classic`, level names or kitchen files")
    heldout = dict(heldout_levels())
    base = base_dir or Path()
    out: dict[str, Level] = {}
    for tok in tokens:
        if tok == "heldout":
            out.update(heldout)
        elif tok == "classic":
            out.update({n: classic_level(n) for n in CLASSIC_ASCII})
        elif tok == "generated":
            out.update({n: lv for n, lv in heldout.items() if n.startswith("generated_")})
        elif tok in heldout:
            out[tok] = heldout[tok]
        elif is_path_spec(tok) or (base / tok).exists():
            for name, level in load_kitchens(base / Path(tok).expanduser()).items():
                if name in out:
                    raise ConfigError(f"two kitchens are named {name!r} in levels {spec!r}; rename one file")
                out[name] = level
        else:
            raise ConfigError(
                f"unknown Overcooked level {tok!r}; use heldout, classic, generated, a classic kitchen "
                f"({', '.join(sorted(CLASSIC_ASCII))}), generated_000..generated_099, an ASCII kitchen "
                f"file or a folder of {KITCHEN_SUFFIX} kitchen files"
            )
    return out
