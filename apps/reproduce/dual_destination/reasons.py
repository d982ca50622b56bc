"""Why a number of `cec reproduce dual-destination` differs from the paper's, or one of the paper's
orderings fails, read from the same seeds' other measures (self-play, the oracle partner, greedy play,
conventions, entropy); `report.write_report` puts these lines under its tables.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

from apps.reproduce.dual_destination.paper import LEVEL_SET_TITLES, VARIANT_TITLES
from apps.reproduce.dual_destination.summary import LEARNED, ClaimResult, Score

TOLERANCE = 0.05  # "within 0.05 of the paper's"


#: SP above XP by more than this: the seeds learned the task but do not play one convention.
CONVENTION_GAP = 0.1


def difference_reason(
    xp: Score, paper: float, sp: Score | None, oracle: Score | None, *, trained_on_set: bool = True
) -> str:
    """What the other measures of the same seeds say about an XP score that differs from the paper's:
    whether the seeds learned the task at all (SP), whether they fail only with each other (SP well above
    XP), and how they play with the oracle partner (a best response to whatever they do)."""
    facts = []
    if sp is not None:
        facts.append(f"with themselves (SP) its seeds score {sp.mean:.3f}")
    if oracle is not None:
        facts.append(f"with the oracle partner {oracle.mean:.3f}")
    said = ("Reading: " + " and ".join(facts) + "; ") if facts else "Reading: "
    if not trained_on_set:
        if abs(paper) <= TOLERANCE:  # the paper's value is a failure too: the gap is the scales' floor
            return said + (
                "it never trained on these tasks and fails on them, as in the paper; a policy that never "
                "reaches a goal pair scores -0.5 on our scale (return / 200 with a step cost of -1), where "
                f"the paper reports {paper:.2f} for the same failure, so this gap looks like one of scale."
            )
        return said + (
            f"it never trained on these tasks; the paper reports {paper:.2f} here, so its agents reached "
            f"goal pairs on tasks they never trained on, where ours score {xp.mean:.3f} (a policy that never "
            "reaches a goal pair scores -0.5 on our scale): a gap in generalisation to untrained tasks, "
            "not one of scale."
        )
    if sp is not None and sp.mean - xp.mean > CONVENTION_GAP:
        return said + (
            "the seeds learned the task but settled on conventions that do not match across seeds, so "
            "the gap is in coordination with unseen partners, not in skill."
        )
    if sp is not None and sp.mean < paper - TOLERANCE:
        return said + (
            "they play about as badly with themselves, so at this budget the policy has not learned the "
            "task set to the paper's level (see the Training section)."
        )
    if xp.mean > paper:
        return said + "ours is higher: these seeds coordinate with each other better than the paper's did."
    return said + "the seeds play well with themselves and each other but below the paper's value."


def ordering_reason(
    claim: ClaimResult,
    kinds: dict[str, dict[str, Score]],
    conventions: dict[str, dict[int, str]] | None = None,
    entropy: dict[str, float] | None = None,
) -> str:
    """One line on a failed ordering `better > worse`: whether `worse` coordinates with unseen seeds about
    as well as with itself (the coordination failure the ordering rests on did not occur), whether greedy
    play shows a mismatch that sampled play hides, how many conventions `worse`'s seeds hold (per algorithm
    in `conventions`, the variant's fixed task), whether `better`'s seeds learned the task but split
    into conventions that fail with each other (SP well above XP), how random
    both policies still were at the end of training (`entropy`, per algorithm), whether `better`
    learned the task as well as `worse` did (SP), whether one that fails with itself plays the task with
    the oracle partner (it can reach a goal pair; the failure is one of coordination), and, on tasks that
    neither trained on (IPPO and FCP on generated ones), that the ordering compares two failures."""
    xp, sp = kinds.get("xp", {}), kinds.get("sp", {})
    b, w = claim.better, claim.worse
    head = (
        f"- {VARIANT_TITLES[claim.variant]}, {LEVEL_SET_TITLES[claim.level_set]}, {b.upper()} > {w.upper()}: "
    )
    if b not in sp or w not in sp:
        return head + "no self-play scores to compare."
    parts = [
        f"{w.upper()} XP {xp[w].mean:.3f} vs SP {sp[w].mean:.3f}, {b.upper()} XP {xp[b].mean:.3f} vs SP "
        f"{sp[b].mean:.3f}"
    ]
    if claim.level_set != "fixed" and "cec" not in (b, w):
        parts.append(
            f"neither {b.upper()} nor {w.upper()} trained on these tasks (both train on the fixed task), so "
            "the ordering compares two failures"
        )
    elif sp[w].mean - xp[w].mean <= CONVENTION_GAP:  # two failures coordinate equally badly: beside the point
        parts.append(
            f"{w.upper()}'s seeds coordinate with each other about as well as with themselves, so the "
            "failure with unseen partners that the paper's ordering rests on did not occur"
        )
    gxp, gsp = kinds.get("greedy_xp", {}).get(w), kinds.get("greedy_sp", {}).get(w)
    if gxp is not None and gsp is not None:
        hidden = gsp.mean - gxp.mean > CONVENTION_GAP >= sp[w].mean - xp[w].mean
        parts.append(
            f"greedy, {w.upper()} XP {gxp.mean:.3f} vs SP {gsp.mean:.3f}"
            + (": its seeds' conventions differ, and sampling hides it" if hidden else "")
        )
    oracle = kinds.get("oracle", {})
    for a in (w, b):
        unlearned = [seed for seed, v in zip(sp[a].seeds, sp[a].samples, strict=False) if v < LEARNED]
        if unlearned:
            parts.append(
                f"{len(unlearned)} of {sp[a].n_seeds} {a.upper()} seeds did not learn the task (SP < "
                f"{LEARNED}: seed {', '.join(map(str, unlearned))})"
            )
        if a in oracle and sp[a].mean < LEARNED <= oracle[a].mean:
            parts.append(
                f"with the oracle partner, which adapts to what its partner shows, {a.upper()} scores "
                f"{oracle[a].mean:.3f} against SP {sp[a].mean:.3f}: it can reach a goal pair, but does not "
                "coordinate even with a copy of itself"
            )
    conventions = conventions or {}
    if conventions.get(w):
        parts.append(f"{w.upper()}'s seeds send seat 0 to {_convention_counts(conventions[w])}")
    if sp[b].mean >= LEARNED and sp[b].mean - xp[b].mean > CONVENTION_GAP:
        split = f": seat 0 to {_convention_counts(conventions[b])}" if conventions.get(b) else ""
        parts.append(
            f"{b.upper()}'s seeds learned the task (SP {sp[b].mean:.3f}) but do not share one convention"
            f"{split}, so they fail with each other (XP {xp[b].mean:.3f})"
        )
    known = {a: e for a, e in (entropy or {}).items() if a in (w, b) and not math.isnan(e)}
    if known:
        listed = ", ".join(f"{a.upper()} {e:.2f}" for a, e in sorted(known.items(), key=lambda x: x[0] != w))
        parts.append(f"policy entropy at the end of training {listed} (uniform: 1.61)")
    if sp[b].mean < sp[w].mean - TOLERANCE:
        parts.append(f"{b.upper()} also plays the task less well with itself than {w.upper()} does")
    return head + "; ".join(parts) + "."


def _convention_counts(per_seed: dict[int, str]) -> str:
    """`green (0, 2) (3), green (4, 2) (1)`: each goal seat 0 takes and how many seeds take it."""
    return ", ".join(f"{g} ({n})" for g, n in sorted(Counter(per_seed.values()).items()))


#: A training return that rises slower than this per 1e6 env steps at the end has levelled off.
LEVELLED = 0.01


def cec_gap_reason(xp: Score, paper: float, sp: Score | None, training: dict[str, Any]) -> str:
    """Why fully observable CEC's XP is not within TOLERANCE of the paper's, and what more training would
    buy: whether the gap is between seeds (SP well above XP: conventions) or in skill (SP below the
    paper's value), and, from the end of the learning curve (`training`: its `TrainingStats` as a dict,
    empty when not known), whether the training return still rose and how many more env steps a
    straight-line extrapolation needs."""
    parts = []
    if sp is not None:
        gap = sp.mean - xp.mean
        parts.append(
            f"its seeds score {sp.mean:.3f} with themselves (SP)"
            + (
                f", {gap:.3f} above their XP: that much of the gap is between seeds, whose conventions "
                "differ (the Conventions section), not in how well each plays"
                if gap > CONVENTION_GAP
                else ""
            )
        )
    slope = training.get("late_slope", math.nan)
    if not math.isnan(slope):
        ended = (
            f"its training return ended at {training['final_return']:.3f}, changing {slope:+.3f} per 1e6 "
            "env steps over the last quarter of training (the learning curves in the Training section)"
        )
        short = math.nan if sp is None else paper - sp.mean
        if slope < LEVELLED:
            parts.append(
                ended
                + ": it levelled off, so more steps of the same training are not predicted to close the gap"
            )
        elif short > TOLERANCE:
            more = short / slope * 1e6
            hours = more * training["seconds"] / max(training["env_steps"], 1) / 3600
            parts.append(
                ended
                + f": at that rate (a straight-line extrapolation) SP would gain the missing {short:.3f} "
                f"in about {more:.1e} more env steps per seed, {hours:.1f} h of one core for all its seeds "
                "at this run's speed"
            )
        else:
            parts.append(ended)
    return ("; ".join(parts) + ".") if parts else "No self-play or training record to say why."
