"""A shipping choice that fails closed: the one rule every command that picks what ships goes through
(`cec partners finetune`'s seed and family, `cec partners best`'s partner per kitchen, `cec release`).

    chosen = choose({"cec": with_bc_of_cec, "cec_finetune": with_bc_of_ft}, what="cramped_room: the partner",
                    skipped=[s for s in table.skipped if s.algorithm in used])

Each candidate is a group of figures (one per seed, say: its mean return with the validation proxy); the
candidate with the highest mean is chosen, the first of them on a tie (so list the incumbent first). Nothing
is chosen, and `ChoiceError` names the cause and the fix, when any candidate's group is empty or holds a value
that is not finite (a partner the evaluation could not play leaves NaN behind), or when the evaluation
skipped an entry of a group the choice uses (`skipped`: the zoo entries `cec eval` could not load, with its
reason), since then the figures are not those of the whole group: a damaged checkpoint must stop a release,
never change what it ships.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

from cec.agents.zoo import SkippedEntry
from cec.config import ConfigError

#: How much of a skipped entry's reason a message repeats.
REASON_CHARS = 300


class ChoiceError(ConfigError):
    """A choice was refused: a group it uses is empty or not finite, or an entry of one was skipped."""


def choose(figures: Mapping[str, Iterable[float]], *, what: str, skipped: Sequence[SkippedEntry] = ()) -> str:
    """The key of `figures` whose values have the highest mean (the first such key on a tie).

    `figures`: candidate -> its group's figures (floats); `what`: what is being chosen, for the message
    (e.g. "cramped_room: the shipped seed"); `skipped`: the entries of the groups used (candidates and the
    partners their figures are with) that the evaluation skipped. `ChoiceError` (a `ConfigError`: exit status
    2 at a command) when there is no candidate, a group is empty or not finite, or `skipped` is not empty.
    """
    groups = {str(name): [float(v) for v in values] for name, values in figures.items()}
    problems = [
        f"{name} has no figure" if not values else f"{name} has a figure that is not finite ({_bad(values)})"
        for name, values in groups.items()
        if not values or not all(math.isfinite(v) for v in values)
    ]
    if not groups:
        problems.append("there is no candidate")
    if skipped:
        problems.append(
            "the evaluation skipped "
            + "; ".join(
                f"{s.name!r} (algorithm {s.algorithm!r}, seed {s.seed}): {_reason(s.reason)}" for s in skipped
            )
        )
    if problems:
        raise ChoiceError(
            f"{what}: refusing to choose, nothing was chosen or written: {'; '.join(problems)}. Repair or "
            "replace the entry named (its checkpoint: `cec eval` says why it skipped it) and run the "
            "evaluation again"
        )
    means = {name: math.fsum(values) / len(values) for name, values in groups.items()}
    best = max(means.values())
    return next(name for name, mean in means.items() if mean == best)


def _bad(values: Sequence[float]) -> str:
    bad = [v for v in values if not math.isfinite(v)]
    return f"{len(bad)} of {len(values)} are {', '.join(sorted({repr(v) for v in bad}))}"


def _reason(reason: str) -> str:
    flat = " ".join(str(reason).split())
    return flat if len(flat) <= REASON_CHARS else flat[: REASON_CHARS - 3] + "..."


__all__ = ["ChoiceError", "choose"]
