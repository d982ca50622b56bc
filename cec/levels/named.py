"""Overcooked kitchens by name, file or folder: the one resolver every command that names levels uses.

A level spec is a comma-separated list of tokens, each one of

    heldout            the validation set, once called the held-out set (5 classic + 100 generated kitchens);
                       `validation` is the same set
    classic            the 5 classic kitchens;  cramped_room, ... one of them
    generated          the 100 generated validation kitchens;  generated_000 .. generated_099 one of them
    test               the test set (100 generated kitchens test_000 .. test_099 and the kitchens people
                       drew for overcooked-ai, drawn_<layout>; `cec.levels.heldout`); one of them by name
    test2              the second test set (100 generated kitchens test2_000 .. test2_099); one by name
    generated:SEED     the procedural generator's kitchen for SEED (`generated:random` where one kitchen is
                       asked for: a seed drawn per use, see `resolve_level`)
    path/to/file.txt   an ASCII kitchen file (`cec.levels.ascii`), named by its stem
    path/to/folder/    every `*.txt` kitchen file in the folder, sorted by name

`resolve_levels` resolves a spec to {name: level}; `resolve_level` one kitchen (what `cec play`, `cec
render` and `cec levels show` take), `check_level` checks such a name without building the kitchen.

Relative paths are taken from `base_dir` (the working directory unless given). Files are read with a size
bound, parsed and checked for solvability here, so a malformed or unsolvable kitchen is refused with its
reason (a `ConfigError` naming the file) before anything is compiled for it.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np

from cec.config import ConfigError
from cec.levels.ascii import from_ascii
from cec.levels.classic import CLASSIC_ASCII, classic_level
from cec.levels.level import Level, LevelError

MAX_KITCHEN_FILE_BYTES = 64 * 1024
KITCHEN_SUFFIX = ".txt"
SET_NAMES = ("heldout", "validation", "classic", "generated", "test", "test2")
GENERATED_PREFIX = "generated:"
RANDOM_SEED = "random"


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
    from cec.levels.heldout import heldout_levels, test2_levels, test_levels

    tokens = _tokens(spec)
    if not tokens:
        raise ConfigError("levels is empty; give e.g. `heldout`, `classic`, level names or kitchen files")
    heldout, test = dict(heldout_levels()), {**dict(test_levels()), **dict(test2_levels())}
    test2 = {n: lv for n, lv in test.items() if n.startswith("test2_")}
    base = base_dir or Path()
    out: dict[str, Level] = {}
    for tok in tokens:
        if tok in ("heldout", "validation"):
            out.update(heldout)
        elif tok == "test":
            out.update({n: lv for n, lv in test.items() if n not in test2})
        elif tok == "test2":
            out.update(test2)
        elif tok in test:
            out[tok] = test[tok]
        elif tok == "classic":
            out.update({n: classic_level(n) for n in CLASSIC_ASCII})
        elif tok == "generated":
            out.update({n: lv for n, lv in heldout.items() if n.startswith("generated_")})
        elif tok in heldout:
            out[tok] = heldout[tok]
        elif tok.startswith(GENERATED_PREFIX):
            out[tok] = generated_level(_generated_seed(tok, allow_random=False))
        elif is_path_spec(tok) or (base / tok).exists():
            for name, level in load_kitchens(base / Path(tok).expanduser()).items():
                if name in out:
                    raise ConfigError(f"two kitchens are named {name!r} in levels {spec!r}; rename one file")
                out[name] = level
        else:
            raise _unknown(tok, "heldout (validation), test, test2, classic, generated, ")
    return out


def _unknown(token: str, sets: str = "") -> ConfigError:
    classic = ", ".join(sorted(CLASSIC_ASCII))
    return ConfigError(
        f"unknown Overcooked level {token!r}; use {sets}a classic kitchen ({classic}), generated_000.."
        f"generated_099, test_000..test_099, test2_000..test2_099, drawn_<layout>, generated:SEED, an ASCII "
        "kitchen file or a "
        f"folder of {KITCHEN_SUFFIX} kitchen files"
    )


def _generated_seed(token: str, allow_random: bool) -> int | None:
    """The seed of `generated:SEED` (None for `generated:random`); `ConfigError` if it is neither."""
    text = token[len(GENERATED_PREFIX) :]
    if allow_random and text == RANDOM_SEED:
        return None
    if not text.isdigit() or int(text) >= 2**31:
        also = " or generated:random" if allow_random else ""
        raise ConfigError(f"level {token!r}: write generated:SEED with an integer 0 <= SEED < 2**31{also}")
    return int(text)


@cache
def generated_level(seed: int) -> Level:
    """The procedural generator's kitchen for `seed` (its default settings; held-out kitchens included)."""
    import jax

    from cec.levels.generator import GeneratorConfig, generate_batch
    from cec.levels.level import unstack_levels

    batch = generate_batch(jax.random.PRNGKey(seed), 1, GeneratorConfig())
    level: Level = jax.device_get(unstack_levels(batch)[0])
    return level


def _kitchen_file(token: str, base_dir: Path | None) -> Path | None:
    """The ASCII kitchen file a one-kitchen token names (None for a classic or held-out name);
    `ConfigError` if it names neither (a set, a folder, nothing)."""
    from cec.levels.heldout import heldout_levels, test2_levels, test_levels

    named = (*heldout_levels(), *test_levels(), *test2_levels())
    if token in CLASSIC_ASCII or token in dict(named):
        return None
    path = (base_dir or Path()) / Path(token).expanduser()
    if not path.is_file():
        raise _unknown(token)
    return path


def check_level(token: str, base_dir: Path | None = None) -> None:
    """`ConfigError` naming the problem if `token` names no single kitchen (nothing is generated; a kitchen
    file is read and checked for solvability)."""
    if token.startswith(GENERATED_PREFIX):
        _generated_seed(token, allow_random=True)
    elif (path := _kitchen_file(token, base_dir)) is not None:
        load_kitchens(path)


def resolve_level(
    token: str, base_dir: Path | None = None, rng: np.random.Generator | None = None
) -> tuple[str, Level]:
    """(name, level) of one kitchen: a classic or held-out name, `generated:SEED` (`generated:random` draws
    the seed from `rng`, and the name records it), or an ASCII kitchen file (named by its stem, read and
    checked once)."""
    if token.startswith(GENERATED_PREFIX):
        seed = _generated_seed(token, allow_random=True)
        if seed is None:
            seed = int((rng or np.random.default_rng()).integers(0, 2**31 - 1))
        return f"{GENERATED_PREFIX}{seed}", generated_level(seed)
    _kitchen_file(token, base_dir)  # refuses a set or a folder before resolve_levels would take it
    ((name, level),) = resolve_levels(token, base_dir).items()
    return name, level
