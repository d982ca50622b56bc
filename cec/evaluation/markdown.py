"""The one place reports write figures and Markdown: numbers with their uncertainty, p-values, intervals,
tables, and templates with named holes. Every report (`cec report`, each `cec reproduce` paper) and every
benchmark that writes a README figure formats through here, so one figure reads the same everywhere.

    pm(12.34, 1.2)                  -> "12.3 ± 1.2"      (no error: "12.3"; no mean: "—")
    pm(12.34, 1.2, n=4)             -> "12.3 ± 1.2 (n=4)"
    table(["a", "b"], [[1, 2]])     -> "| a | b |\\n|---|---|\\n| 1 | 2 |"
    fill(read_template(path), title="...", table="...")
    TEMPLATES = Templates(Path(__file__).parent / "templates")   # a report's folder of NAME.md templates
    TEMPLATES.fill("header", title="...")                           # one of them, filled by name

A template is Markdown with `string.Template` holes (`$name` or `${name}`; `$$` is a dollar sign). `fill`
refuses a hole without a value and a value without a hole, so neither prose nor a figure goes missing
silently.
"""

from __future__ import annotations

import math
import string
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

NONE = "—"  # where there is no figure (an em dash)


def _missing(x: float | None) -> bool:
    return x is None or (isinstance(x, float) and math.isnan(x))


def num(x: float | None, digits: int = 1, *, signed: bool = False) -> str:
    """`x` with `digits` decimals (`signed`: always with its sign), or `NONE` where it is None or NaN."""
    if _missing(x):
        return NONE
    assert x is not None
    return f"{x:+.{digits}f}" if signed else f"{x:.{digits}f}"


def pm(
    mean: float | None,
    err: float | None,
    digits: int = 1,
    *,
    n: int | None = None,
    no_error: str | None = None,
) -> str:
    """A mean with its uncertainty: "mean ± err" with `digits` decimals; the mean alone where `err` is None
    or NaN (or "mean ± `no_error`" when given); `NONE` where the mean is missing. `n`: the sample count,
    appended as " (n=N)"."""
    if _missing(mean):
        return NONE
    assert mean is not None
    text = f"{mean:.{digits}f}"
    if not _missing(err):
        assert err is not None
        text += f" ± {err:.{digits}f}"
    elif no_error is not None:
        text += f" ± {no_error}"
    return text + ("" if n is None else f" (n={n})")


def p_value(p: float | None, significant: int = 2) -> str:
    """A p-value with `significant` significant digits, or `NONE`."""
    if _missing(p):
        return NONE
    assert p is not None
    return f"{p:.{significant}g}"


def interval(low: float | None, high: float | None, digits: int = 1, *, signed: bool = True) -> str:
    """A confidence interval "[low, high]" (`signed`: each with its sign), or `NONE` where it has no ends."""
    if _missing(low) or _missing(high):
        return NONE
    return f"[{num(low, digits, signed=signed)}, {num(high, digits, signed=signed)}]"


def row(cells: Iterable[object], *, tight: bool = False) -> str:
    """One Markdown table row: `| a | b |`; an empty cell is `|  |`, or `| |` when `tight`."""
    return "|" + "|".join(" " if tight and str(c) == "" else f" {c} " for c in cells) + "|"


def table_lines(
    headers: Sequence[object], rows: Iterable[Sequence[object]], *, tight: bool = False
) -> list[str]:
    """A Markdown table as lines: the header, its rule and one line per row (`tight`: see `row`)."""
    return [row(headers, tight=tight), "|" + "---|" * len(headers), *(row(r, tight=tight) for r in rows)]


def table(
    headers: Sequence[object], rows: Iterable[Sequence[object]], *, end: str = "", tight: bool = False
) -> str:
    """A Markdown table, followed by `end` (by default no trailing newline; `tight`: see `row`)."""
    return "\n".join(table_lines(headers, rows, tight=tight)) + end


# ---- templates ---------------------------------------------------------------------------------------


def read_template(path: Path) -> string.Template:
    """The template at `path` (Markdown with `string.Template` holes)."""
    return string.Template(path.read_text())


def holes(template: string.Template) -> set[str]:
    """The named holes of `template`; a `$` that is neither a hole nor `$$` is an error."""
    if not template.is_valid():
        raise ValueError(
            f"a stray '$' in the template (write '$$' for a dollar sign): {template.template[:80]!r}"
        )
    return set(template.get_identifiers())


def fill(template: string.Template, values: Mapping[str, object] | None = None, /, **more: object) -> str:
    """`template` with every hole filled from `values` and `more`; a hole without a value or a value without
    a hole is an error (`KeyError` / `ValueError`), so a template and its filler cannot drift apart."""
    given = {**(values or {}), **more}
    wanted = holes(template)
    missing, unused = wanted - given.keys(), given.keys() - wanted
    if missing:
        raise KeyError(f"template holes without a value: {', '.join(sorted(missing))}")
    if unused:
        raise ValueError(f"values without a hole in the template: {', '.join(sorted(unused))}")
    return template.substitute({k: str(v) for k, v in given.items()})


class Templates:
    """The Markdown templates of one folder (`NAME.md`), filled by name. It remembers which it filled, so a
    test can render a report on small inputs and check that every template of its folder was filled (`fill`
    already refuses a hole without a value and a value without a hole)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.filled: set[str] = set()

    def names(self) -> set[str]:
        """Every template of the folder, by name."""
        return {p.stem for p in self.folder.glob("*.md")}

    def fill(self, name: str, values: Mapping[str, object] | None = None, /, **more: object) -> str:
        """The template `name` filled with `values` and `more` (see `fill`)."""
        text = fill(read_template(self.folder / f"{name}.md"), values, **more)
        self.filled.add(name)
        return text

    def lines(self, name: str, values: Mapping[str, object] | None = None, /, **more: object) -> list[str]:
        """`fill`'s text as lines (a template that ends with a newline ends with an empty line)."""
        return self.fill(name, values, **more).split("\n")
