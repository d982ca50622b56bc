"""What the paper reports on Dual Destination: its variants, task sets and algorithms, and its numbers.

The numbers, the orderings the paper states and the oracle's ceiling are data, in
`apps/reproduce/paper_dual_destination.yaml` (where they come from is in its header). They are read and
checked once, when this module is imported: a malformed file raises `ConfigError` naming the file and the
key. `cec reproduce dual-destination` (`command`) and its report (`report`) use them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from cec.config import ConfigError

PAPER_FILE = Path(__file__).parents[1] / "paper_dual_destination.yaml"
VARIANTS = ("full_obs", "partial_obs", "multi_task")
VARIANT_TITLES = {
    "full_obs": "Fully observable",
    "partial_obs": "Partially observable (3x3 view)",
    "multi_task": "Multi-task (green and pink pairs)",
}
ALGORITHMS = ("ippo", "fcp", "cec")


@dataclass(frozen=True)
class Ablation:
    """A variation of one algorithm that a version may train beside it (its preset with `overrides` last),
    reported as its own row and tested against that algorithm, not in the paper's orderings.

    Attributes:
        algorithm: the algorithm it varies; title: what it is, for the report; claim: what the paper says
            about it; overrides: what it changes.
    """

    algorithm: str
    title: str
    claim: str
    overrides: tuple[str, ...]


ABLATIONS = {
    "cec_nolstm": Ablation(
        "cec",
        "CEC without an LSTM",
        "In 300 million timesteps, CEC without an LSTM cannot achieve a positive reward on the Dual "
        "Destination problem (the paper's appendix; with the LSTM it converges to the maximum reward)",
        ("network_overrides.lstm_features=0",),
    )
}
ROWS = (*ALGORITHMS, *ABLATIONS)  # every algorithm label a report may show
ORACLE = "oracle"
LEVEL_SETS = ("fixed", "generated")  # the fixed task (multi_task layout in that variant); 100 generated tasks
LEVEL_SET_TITLES = {"fixed": "fixed task", "generated": "held-out generated tasks"}
FIGURE_ONLY = "figure only:"  # how the text of a number the paper shows only in a figure starts


def fixed_level_name(variant: str) -> str:
    """The variant's fixed task: the paper's fixed task, or its multi-task layout."""
    return "multi_task" if variant == "multi_task" else "fixed"


@dataclass(frozen=True)
class PaperNumber:
    """One number the paper reports: normalised cross-play with unseen partners.

    Attributes:
        variant, level_set, algorithm: where it belongs.
        mean: the paper's value, or None where the paper shows it only in a figure.
        sem: its standard error where the paper gives one.
        text: how the paper states it.
    """

    variant: str
    level_set: str
    algorithm: str
    mean: float | None
    sem: float | None
    text: str


@dataclass(frozen=True)
class PaperResults:
    """The contents of `paper_dual_destination.yaml`.

    Attributes:
        numbers: the paper's numbers, in the file's order.
        claims: (variant, level set, better, worse): the orderings the paper states.
        oracle_fixed: the oracle's normalised score on the fixed task (the paper's ceiling).
        source: where they come from.
    """

    numbers: tuple[PaperNumber, ...]
    claims: tuple[tuple[str, str, str, str], ...]
    oracle_fixed: float
    source: str


Fail = Callable[[str, str], ConfigError]  # (key, problem) -> the error naming the file and the key
_NUMBER_KEYS = ("variant", "level_set", "algorithm", "mean", "sem", "text")
_CLAIM_KEYS = ("variant", "level_set", "better", "worse")
_CHOICES = {
    "variant": VARIANTS,
    "level_set": LEVEL_SETS,
    "algorithm": ALGORITHMS,
    "better": ALGORITHMS,
    "worse": ALGORITHMS,
}


def load_paper(path: Path = PAPER_FILE) -> PaperResults:
    """Reads and checks the paper's numbers; raises `ConfigError` naming `path` and the key at fault."""

    def fail(key: str, problem: str) -> ConfigError:
        return ConfigError(f"{path}: {key}: {problem}")

    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise ConfigError(f"{path}: cannot read the paper's numbers: {e}") from e
    if not isinstance(data, dict):
        raise fail("(top level)", "expected a mapping with source, oracle_fixed, numbers and claims")
    _keys(data, ("source", "oracle_fixed", "numbers", "claims"), "(top level)", fail)
    source = data["source"]
    if not isinstance(source, str) or not source.strip():
        raise fail("source", f"expected where the numbers come from (text), got {source!r}")
    oracle_fixed = _number(data["oracle_fixed"], "oracle_fixed", fail)

    numbers: list[PaperNumber] = []
    for i, entry in enumerate(_list(data["numbers"], "numbers", fail)):
        where = f"numbers[{i}]"
        names = _names(entry, _NUMBER_KEYS, where, fail)
        mean = None if entry["mean"] is None else _number(entry["mean"], f"{where}.mean", fail)
        sem = None if entry["sem"] is None else _number(entry["sem"], f"{where}.sem", fail)
        text = entry["text"]
        if not isinstance(text, str) or not text.strip():
            raise fail(f"{where}.text", f"expected how the paper states it (text), got {text!r}")
        if (mean is None) != text.startswith(FIGURE_ONLY):
            raise fail(
                f"{where}.text",
                f"a number shown only in a figure has mean null and a text starting {FIGURE_ONLY!r}, and "
                f"only such a number (mean {mean}, text {text!r})",
            )
        if sem is not None and (mean is None or sem < 0):
            raise fail(f"{where}.sem", f"a standard error needs a mean and must be >= 0 (got {sem})")
        if any(
            p.variant == names[0] and p.level_set == names[1] and p.algorithm == names[2] for p in numbers
        ):
            raise fail(where, f"a second number for {'/'.join(names)}")
        numbers.append(PaperNumber(names[0], names[1], names[2], mean, sem, text))

    claims: list[tuple[str, str, str, str]] = []
    for i, entry in enumerate(_list(data["claims"], "claims", fail)):
        where = f"claims[{i}]"
        variant, level_set, better, worse = _names(entry, _CLAIM_KEYS, where, fail)
        if better == worse:
            raise fail(f"{where}.worse", f"an ordering of {better} against itself")
        if (variant, level_set, better, worse) in claims:
            raise fail(where, "the same ordering twice")
        claims.append((variant, level_set, better, worse))
    return PaperResults(tuple(numbers), tuple(claims), oracle_fixed, source)


def _keys(entry: Mapping[str, object], keys: tuple[str, ...], where: str, fail: Fail) -> None:
    missing = [k for k in keys if k not in entry]
    unknown = [str(k) for k in entry if k not in keys]
    if missing or unknown:
        raise fail(where, f"missing key(s) {missing}, unknown key(s) {unknown}; expected {list(keys)}")


def _list(value: object, where: str, fail: Fail) -> list[Any]:
    if not isinstance(value, list) or not value:
        raise fail(where, f"expected a non-empty list, got {value!r}")
    return value


def _names(entry: object, keys: tuple[str, ...], where: str, fail: Fail) -> tuple[str, ...]:
    """Checks `entry`'s keys, and the choice-valued ones against their choices; returns those values."""
    if not isinstance(entry, dict):
        raise fail(where, f"expected a mapping with {list(keys)}, got {entry!r}")
    _keys(entry, keys, where, fail)
    for key in (k for k in keys if k in _CHOICES):
        if entry[key] not in _CHOICES[key]:
            raise fail(f"{where}.{key}", f"{entry[key]!r} is not one of {list(_CHOICES[key])}")
    return tuple(str(entry[k]) for k in keys if k in _CHOICES)


def _number(value: object, where: str, fail: Fail) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise fail(where, f"expected a number, got {value!r}")
    return float(value)


_PAPER = load_paper()
PAPER: tuple[PaperNumber, ...] = _PAPER.numbers
#: (variant, level set, better, worse): the orderings the paper states.
CLAIMS: tuple[tuple[str, str, str, str], ...] = _PAPER.claims
#: The oracle's normalised score on the fixed task (the paper's ceiling).
ORACLE_FIXED: float = _PAPER.oracle_fixed


def paper_number(variant: str, level_set: str, algorithm: str) -> PaperNumber | None:
    return next(
        (p for p in PAPER if (p.variant, p.level_set, p.algorithm) == (variant, level_set, algorithm)), None
    )
