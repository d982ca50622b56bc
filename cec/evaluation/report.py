"""`cec report`: a Markdown report with PNG figures, derived from one or more result tables.

For each level set (classic kitchens, held-out generated kitchens, each Dual Destination task):
SP/XP/ad-hoc scores and BR-normalised scores per algorithm, seed x seed matrices, the cross-algorithm
heatmap, per-level bars with standard errors, significance tests between algorithms (Welch t-test and
bootstrap interval), and the meta-game analysis (replicator gradient, rest points, alpha-rank). Skipped
zoo entries are listed with their reasons at the top.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cec.agents.zoo import HUMAN_PROXY
from cec.evaluation import analysis as an
from cec.evaluation import egta
from cec.evaluation.markdown import NONE, Templates, num, p_value, pm, table
from cec.evaluation.plotting import colour_range, distinct_colours, pyplot
from cec.evaluation.results import EpisodeTable
from cec.evaluation.stats import (
    compare,
    compare_crossplay,
    crossplay_estimate,
    holm,
    permutation_crossplay,
    sem,
)

TEMPLATES = Templates(Path(__file__).parent / "templates")

#: Heatmaps of more rows than this show colours without a value in each cell, at this size.
MAX_CELL_TEXT = 12
MAX_BARS = 12  # level sets with more levels get one aggregate bar per algorithm instead of per-level bars


def rank_order(mass: np.ndarray, labels: Sequence[str]) -> list[int]:
    """Indices by stationary mass as the report prints it (3 decimals), ties by label: masses that print
    alike (0.000) differ only by solver noise, and their order must not change from one run to the next."""
    return sorted(range(len(mass)), key=lambda i: (-round(float(mass[i]), 3), labels[i]))


def _slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


def _matrix_md(m: an.Matrix, digits: int) -> str:
    rows = [[m.labels[i], *(num(v, digits) for v in m.values[i])] for i in range(len(m.labels))]
    return table(["", *m.labels], rows, end="\n")


def _heatmap(
    ax: Any, m: an.Matrix, title: str, digits: int, vmin: float | None = None, vmax: float | None = None
) -> None:
    """A labelled heatmap with the values written in the cells (NaN cells left blank)."""
    vals = np.ma.masked_invalid(m.values)
    if vmin is None or vmax is None:
        vmin, vmax = colour_range(m.values)
    im = ax.imshow(vals, cmap="viridis", vmin=vmin, vmax=vmax)
    ax.set_xticks(range(len(m.labels)), m.labels, rotation=45, ha="right")
    ax.set_yticks(range(len(m.labels)), m.labels)
    ax.set_title(title)
    low, high = im.get_clim()
    if len(m.labels) > MAX_CELL_TEXT:  # a value per cell is unreadable there, and costs memory per cell
        ax.figure.colorbar(im, ax=ax, fraction=0.046)
        return
    for i in range(len(m.labels)):
        for j in range(len(m.labels)):
            v = m.values[i, j]
            if not math.isnan(v):
                bright = high > low and (v - low) / (high - low) > 0.6  # viridis turns yellow at the top
                color = "k" if bright else "w"
                ax.text(j, i, f"{v:.{digits}f}", ha="center", va="center", color=color, fontsize=7)
    ax.figure.colorbar(im, ax=ax, fraction=0.046)


class _Report:
    def __init__(self, table: EpisodeTable, out_dir: Path, sources: Sequence[str]) -> None:
        self.table = table
        self.out = out_dir
        self.sources = sources
        self.env, self.steps = an.check_single_env(table)
        self.normalised = an.normalised_score(self.env)
        self.digits = 3 if self.normalised else 1
        self.unit = "normalised score (return / (2 x episode length))" if self.normalised else "team return"
        self.md: list[str] = []
        self.figures: list[Path] = []

    def save(self, fig: Any, name: str) -> str:
        path = self.out / name
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        pyplot().close(fig)
        self.figures.append(path)
        return name

    # ---- sections ------------------------------------------------------------------------------------

    def header(self) -> None:
        t = self.table
        actions = ", ".join(sorted(set(t.actions.tolist())))
        self.md.append(
            TEMPLATES.fill(
                "header",
                env=self.env,
                steps=self.steps,
                actions=actions,
                episodes=len(t),
                files=len(self.sources) or 1,
                sources=", ".join(self.sources) or "-",
                unit=self.unit,
            )  # fmt: skip
        )
        if t.skipped:
            self.md.append("## Skipped zoo entries\n")
            self.md.append(
                "These entries are **absent from every matrix below**; fix the cause and evaluate again.\n"
            )
            rows = [
                [s.name, s.algorithm or "?", str(s.seed) if s.seed >= 0 else "?", s.reason] for s in t.skipped
            ]
            self.md.append(table(["entry", "algorithm", "seed", "reason"], rows, end="\n"))
        policies = an.policies_of(t)
        by_algo: dict[str, list[int]] = {}
        for p in policies:
            by_algo.setdefault(p.algorithm, []).append(p.seed)
        self.md.append("## Policies\n")
        self.md.append(
            table(
                ["algorithm", "seeds"],
                [[a, ", ".join(map(str, s))] for a, s in sorted(by_algo.items())],
                end="\n",
            )
        )

    def level_set(self, name: str, levels: list[str]) -> None:
        pl = an.pair_level_scores(self.table, levels)
        slug = _slug(name)
        d = self.digits
        self.md.append(f"## Level set: {name} ({len(levels)} level{'s' if len(levels) > 1 else ''})\n")
        # The oracle is Dual Destination's own (cec/envs/dual_destination/oracle.py), no other game has one.
        if self.env == "dual_destination":
            self.oracle_note(levels)

        # Summary per algorithm.
        sp, adhoc, human = (an.algorithm_samples(pl, k) for k in ("sp", "adhoc", "human"))
        with_humans = any(p.algorithm == HUMAN_PROXY for p in pl.policies)
        prox = an.br_prox(pl)
        rows = []
        for alpha in an.algorithms_of(pl.policies):
            b = prox.get(alpha)
            row = [
                alpha,
                str(len(sp.get(alpha, []))),
                pm(*_mean_sem(sp.get(alpha)), d),
                pm(*crossplay_estimate(an.seed_matrix(pl, alpha).values)[:2], d),
                pm(*_mean_sem(adhoc.get(alpha)), d),
            ]
            if with_humans:
                row.append(NONE if alpha == HUMAN_PROXY else pm(*_mean_sem(human.get(alpha)), d))
            rows.append([*row, NONE if b is None else f"{b.iqm:.2f} [{b.q25:.2f}, {b.q75:.2f}]"])
        heads = ["algorithm", "seeds", "SP", "XP (other seeds)", "ad hoc (other algorithms)"]
        if with_humans:
            heads.append("with human proxies")
        self.md.append("### Scores per algorithm\n")
        self.md.append(table([*heads, "BR-prox IQM [IQR]"], rows, end="\n"))
        self.md.append(TEMPLATES.fill("scores"))
        if with_humans:
            self.md.append(TEMPLATES.fill("human_proxies", proxy=HUMAN_PROXY))
        self.seed_matrices(pl, slug)
        self.algorithm_heatmap(pl, name, slug)
        self.per_level(pl, levels, name, slug)
        self.tests(pl)
        self.meta_game(pl, name, slug)

    def oracle_note(self, levels: list[str]) -> None:
        from cec.envs import dual_destination as dd

        known = {"fixed": dd.fixed_level, "multi_task": dd.multi_task_level}
        rows = []
        for lv in levels:
            if lv in known:
                params = dd.DDParams(max_steps=self.steps, multi_task=lv == "multi_task")
                ret = dd.oracle_return(known[lv](), params)
                rows.append([lv, f"{ret:.0f}", f"{float(dd.normalised_score(ret, self.steps)):.3f}"])
        if rows:
            self.md.append("Oracle (both seats planned together; the ceiling of any pair):\n")
            self.md.append(table(["level", "oracle return", "oracle normalised"], rows, end="\n"))

    def seed_matrices(self, pl: an.PairLevel, slug: str) -> None:
        plt = pyplot()
        algos = an.algorithms_of(pl.policies)
        mats = [an.seed_matrix(pl, a) for a in algos]
        # One colour scale for every algorithm, so that the panels compare.
        vmin, vmax = colour_range(np.concatenate([m.values.ravel() for m in mats]))
        cols = min(3, len(algos))
        rows = math.ceil(len(algos) / cols)
        fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.8 * rows), squeeze=False)
        for ax in axes.flat[len(algos) :]:
            ax.axis("off")
        for ax, alpha, m in zip(axes.flat, algos, mats, strict=False):
            _heatmap(ax, m, f"{alpha}: seed x seed", self.digits, vmin, vmax)
        name = self.save(fig, f"seed_matrices_{slug}.png")
        self.md.append("### Seed x seed matrices (SP on the diagonal, XP off it)\n")
        self.md.append(f"![seed x seed matrices]({name})\n")
        for alpha, m in zip(algos, mats, strict=True):
            self.md.append(f"**{alpha}**\n")
            self.md.append(_matrix_md(m, self.digits))

    def algorithm_heatmap(self, pl: an.PairLevel, set_name: str, slug: str) -> None:
        plt = pyplot()
        m = an.algorithm_matrix(pl)
        k = len(m.labels)
        k = min(k, MAX_CELL_TEXT)  # the figure stops growing there (the committed tables hold 12)
        fig, ax = plt.subplots(figsize=(1.2 * k + 2.5, 1.1 * k + 1.8))
        _heatmap(ax, m, f"cross-algorithm play, {set_name}", self.digits)
        name = self.save(fig, f"algorithms_{slug}.png")
        self.md.append("### Cross-algorithm heatmap\n")
        self.md.append(f"![cross-algorithm heatmap]({name})\n")
        self.md.append("Cell = mean pair score of different policies of the two algorithms.\n")
        self.md.append(_matrix_md(m, self.digits))

    def per_level(self, pl: an.PairLevel, levels: list[str], set_name: str, slug: str) -> None:
        plt = pyplot()
        stats = an.per_level(pl, "xp")
        if not stats:
            self.md.append("### Per level\n\nNo algorithm has two seeds on these levels: no XP per level.\n")
            return
        algos = sorted({s.algorithm for s in stats})  # an algorithm with one seed has no XP
        self.md.append("### XP per level\n")
        if len(levels) <= MAX_BARS:
            lv_names = sorted({s.level for s in stats})
            width = 0.8 / max(len(algos), 1)
            wide = min(100.0, 1.3 * len(lv_names) * max(1, len(algos)) / 2)  # 11,000 pixels at most
            fig, ax = plt.subplots(figsize=(max(6.0, wide), 4))
            for k, (alpha, colour) in enumerate(zip(algos, distinct_colours(len(algos)), strict=True)):
                got = {s.level: s for s in stats if s.algorithm == alpha}
                xs = [i + k * width for i, lv in enumerate(lv_names) if lv in got]
                ax.bar(
                    xs,
                    [got[lv].mean for lv in lv_names if lv in got],
                    width,
                    yerr=[0 if math.isnan(got[lv].sem) else got[lv].sem for lv in lv_names if lv in got],
                    capsize=3,
                    color=colour,
                    label=alpha,
                )
            ax.set_xticks(
                [i + width * (len(algos) - 1) / 2 for i in range(len(lv_names))], lv_names, rotation=20
            )
            ax.set_ylabel(self.unit)
            ax.set_title(f"XP per level ({set_name}), standard error bars")
            ax.legend()
            name = self.save(fig, f"per_level_{slug}.png")
            self.md.append(f"![XP per level]({name})\n")
            rows = [[s.level, s.algorithm, pm(s.mean, s.sem, self.digits), str(s.n)] for s in stats]
            self.md.append(table(["level", "algorithm", "XP mean ± SE", "pairs"], rows, end="\n"))
        else:
            fig, ax = plt.subplots(figsize=(6, 4))
            for alpha, colour in zip(algos, distinct_colours(len(algos)), strict=True):
                level_means = [s.mean for s in stats if s.algorithm == alpha]
                ax.hist(level_means, bins=20, alpha=0.5, color=colour, label=alpha)
            ax.set_xlabel(f"XP {self.unit} on one level")
            ax.set_ylabel("levels")
            ax.set_title(f"distribution of per-level XP ({set_name})")
            ax.legend()
            name = self.save(fig, f"per_level_{slug}.png")
            self.md.append(f"{len(levels)} levels: the distribution of per-level XP means.\n")
            self.md.append(f"![per-level XP distribution]({name})\n")
            rows = []
            for alpha in algos:
                means = np.asarray([s.mean for s in stats if s.algorithm == alpha])
                rows.append(
                    [
                        alpha,
                        str(means.size),
                        pm(float(means.mean()), sem(means), self.digits),
                        num(float(np.median(means)), self.digits),
                    ]
                )
            self.md.append(table(["algorithm", "levels", "mean ± SE over levels", "median"], rows, end="\n"))

    def tests(self, pl: an.PairLevel) -> None:
        self.md.append(TEMPLATES.fill("tests"))
        algos = [a for a in an.algorithms_of(pl.policies) if a != HUMAN_PROXY]
        matrices = {a: an.seed_matrix(pl, a).values for a in algos}
        scores = an.pair_scores(pl)
        index = {a: [i for i, p in enumerate(pl.policies) if p.algorithm == a] for a in algos}

        def exact(a: str, b: str) -> tuple[float, float]:
            """The permutation p and its smallest attainable value; NaN where the pooled matrix has a hole
            (two seeds that never played), a side has fewer than 2 seeds or the splits are too many."""
            idx = index[a] + index[b]
            pooled = scores[np.ix_(idx, idx)]
            if min(len(index[a]), len(index[b])) < 2 or np.isnan(pooled[~np.eye(len(idx), dtype=bool)]).any():
                return math.nan, math.nan
            try:
                r = permutation_crossplay(pooled, len(index[a]))
            except ValueError:  # more splits than it enumerates (many seeds): the t-test only
                return math.nan, math.nan
            return r.p, r.p_min

        kinds: list[tuple[str, Any, Any]] = [
            (
                "XP (other seeds of the same algorithm)",
                lambda a, b: compare_crossplay(matrices[a], matrices[b]),
                exact,
            )
        ]
        for kind, label in (("adhoc", "ad hoc"), ("human", "with human proxies")):
            samples = an.seed_samples(pl, kind)
            if any(samples[a].size for a in algos):
                kinds.append((label, lambda a, b, s=samples: compare(s[a], s[b]), None))
        d = self.digits
        for label, test, permutation in kinds:
            found: list[tuple[str, str, Any, tuple[float, float]]] = []
            for i, a in enumerate(algos):
                for b in algos[i + 1 :]:
                    c = test(a, b)
                    if c.n_a == 0 or c.n_b == 0:
                        continue
                    found.append((a, b, c, permutation(a, b) if permutation else (math.nan, math.nan)))
            self.md.append(f"**{label}**\n")
            if not found:
                self.md.append("Fewer than two algorithms with samples.\n")
                continue
            holm_t = holm([c.p for *_, c, _ in found])
            holm_exact = holm([e[0] for *_, e in found])
            rows = []
            for (a, b, c, (p_exact, p_min)), h_t, h_exact in zip(found, holm_t, holm_exact, strict=True):
                row = [
                    f"{a} vs {b}",
                    f"{num(c.mean_a, self.digits)} vs {num(c.mean_b, self.digits)}",
                    f"{c.n_a} / {c.n_b}",
                    f"{num(c.diff, d)} [{num(c.ci_low, d)}, {num(c.ci_high, d)}]",
                    num(c.t, 2),
                    num(c.df, 1),
                    p_value(c.p),
                    p_value(h_t),
                ]
                if permutation:
                    row += [
                        NONE if math.isnan(p_exact) else f"{p_value(p_exact)} ({p_value(p_min)})",
                        p_value(h_exact),
                    ]
                rows.append(row)
            head = ["pair", "means", "seeds", "difference [95% CI]", "t", "df", "p", "Holm p"]
            if permutation:
                head += ["exact p (smallest possible)", "Holm exact p"]
            self.md.append(table(head, rows, end="\n"))
            if permutation and any(math.isnan(e[0]) for *_, e in found):
                self.md.append(
                    "Exact p '—': the two algorithms' seeds did not all play each other (no pooled seed x "
                    "seed matrix), a side has fewer than 2 seeds, or the splits of the seeds are too many to "
                    "enumerate.\n"
                )

    def meta_game(self, pl: an.PairLevel, set_name: str, slug: str) -> None:
        m = an.algorithm_matrix(pl)
        strategies = [i for i, a in enumerate(m.labels) if a != HUMAN_PROXY]  # partners, not a strategy
        m = an.Matrix(tuple(m.labels[i] for i in strategies), m.values[np.ix_(strategies, strategies)])
        self.md.append("### Meta-game: replicator dynamics on the cross-algorithm game\n")
        k = len(m.labels)
        if k < 2 or np.isnan(m.values).any():
            self.md.append(
                "Needs at least two algorithms and every cell of the cross-algorithm matrix "
                "(an algorithm with one seed has no diagonal cell).\n"
            )
            return
        payoff = egta.symmetrise(m.values)
        uniform = np.full(k, 1.0 / k)
        grad = egta.replicator_gradient(payoff, uniform)
        points = egta.rest_points(payoff)
        traj = egta.integrate(payoff, uniform)
        plt = pyplot()
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        axes[0].bar(m.labels, grad)
        axes[0].axhline(0, color="k", lw=0.5)
        axes[0].set_title("replicator gradient dx/dt at the uniform mixture")
        if k == 3:
            axes[1].remove()
            ax = fig.add_subplot(1, 2, 2)
            _simplex(ax, payoff, m.labels, points)
        else:
            for i, (label, colour) in enumerate(zip(m.labels, distinct_colours(k), strict=True)):
                axes[1].plot(traj[:, i], color=colour, label=label)
            axes[1].set_xlabel("time (steps of 0.05, payoffs scaled to unit range)")
            axes[1].set_ylabel("population share")
            axes[1].set_title("replicator trajectory from the uniform mixture")
            axes[1].legend()
        fig.suptitle(f"meta-game, {set_name}")
        name = self.save(fig, f"replicator_{slug}.png")
        self.md.append(f"![replicator dynamics]({name})\n")
        self.md.append(
            table(
                ["algorithm", "dx/dt at uniform", "share after the trajectory"],
                [[lab, f"{grad[i]:+.4g}", f"{traj[-1, i]:.3f}"] for i, lab in enumerate(m.labels)],
                end="\n",
            )
        )
        rows = []
        for r in points:
            mix = ", ".join(f"{m.labels[i]} {r.x[i]:.3f}" for i in r.support)
            rows.append(
                [mix, r.stability, "yes" if r.nash else "no", "yes" if r.isolated else "no (a continuum)"]
            )
        self.md.append("Rest points (stability from the Jacobian on the simplex):\n")
        self.md.append(table(["mixture", "stability", "Nash", "isolated"], rows, end="\n"))
        ar = egta.alpha_rank(payoff)
        if ar.pi is None:
            self.md.append(f"Alpha-rank: {ar.note}.\n")
        else:
            order = rank_order(ar.pi, m.labels)
            self.md.append(f"Alpha-rank ({ar.note}; payoffs scaled to [0, 1]):\n")
            self.md.append(
                table(
                    ["rank", "algorithm", "stationary mass"],
                    [[str(n + 1), m.labels[i], f"{ar.pi[i]:.3f}"] for n, i in enumerate(order)],
                    end="\n",
                )
            )

    def write(self) -> Path:
        self.out.mkdir(parents=True, exist_ok=True)
        self.header()
        for name, levels in an.level_sets(self.table.level.tolist()).items():
            self.level_set(name, levels)
        path = self.out / "report.md"
        path.write_text("\n".join(self.md))
        return path


def _mean_sem(x: np.ndarray | None) -> tuple[float, float]:
    if x is None or x.size == 0:
        return math.nan, math.nan
    return float(x.mean()), sem(x)


def _simplex(ax: Any, payoff: np.ndarray, labels: Sequence[str], points: Sequence[egta.RestPoint]) -> None:
    corners = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, math.sqrt(3) / 2]])
    n = 14
    bary = np.array([[i / n, j / n, 1 - (i + j) / n] for i in range(n + 1) for j in range(n + 1 - i)])
    grad = egta.replicator_gradient(payoff / (float(np.ptp(payoff)) or 1.0), bary)
    xy, dxy = bary @ corners, grad @ corners
    ax.quiver(xy[:, 0], xy[:, 1], dxy[:, 0], dxy[:, 1], angles="xy", color="tab:blue")
    ax.plot(*np.vstack([corners, corners[:1]]).T, color="k", lw=0.8)
    for c, lab in zip(corners, labels, strict=True):
        ax.annotate(lab, c, textcoords="offset points", xytext=(0, -12 if c[1] == 0 else 5), ha="center")
    for r in points:
        p = r.x @ corners
        ax.scatter(*p, s=40, c="k" if r.stability == "stable" else "w", edgecolors="k", zorder=3)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title("replicator field (filled: stable rest point)")


def write_report(table: EpisodeTable, out_dir: str | Path, *, sources: Sequence[str] = ()) -> Path:
    """Writes `report.md` and its PNG figures into `out_dir`; returns the Markdown file's path."""
    return _Report(table, Path(out_dir), sources).write()
