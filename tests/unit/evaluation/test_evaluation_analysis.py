"""Analyses of the result table: statistics against scipy, replicator dynamics of textbook games, matrices,
BR-normalised scores, the results file and the report. Pure NumPy on hand-made tables (no rollouts)."""

import bz2
import gzip
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats as sps

from cec.evaluation import analysis as an
from cec.evaluation import egta
from cec.evaluation.report import rank_order, write_report
from cec.evaluation.results import ResultsError, SkippedEntry, make_table, read_csv, stored, write_csv
from cec.evaluation.stats import (
    bootstrap_diff_ci,
    compare,
    compare_crossplay,
    compare_crossplay_paired,
    crossplay_estimate,
    holm,
    iqm,
    permutation_crossplay,
    seed_means,
    sem,
    welch_ttest,
)

A = np.array([12.1, 9.8, 11.4, 10.2, 13.0, 9.1, 10.7])
B = np.array([8.2, 9.9, 7.1, 8.8, 10.4, 6.5, 9.0, 7.7, 8.1])


# ---- statistics -----------------------------------------------------------------------------------------


def test_welch_t_test_matches_scipy_and_the_textbook_formula():
    t, df, p = welch_ttest(A, B)
    ref = sps.ttest_ind(A, B, equal_var=False)
    assert t == pytest.approx(ref.statistic, rel=1e-12) and p == pytest.approx(ref.pvalue, rel=1e-12)
    assert df == pytest.approx(ref.df, rel=1e-12)
    va, vb = A.var(ddof=1) / A.size, B.var(ddof=1) / B.size
    assert t == pytest.approx((A.mean() - B.mean()) / math.sqrt(va + vb), rel=1e-12)
    assert df == pytest.approx((va + vb) ** 2 / (va**2 / (A.size - 1) + vb**2 / (B.size - 1)), rel=1e-12)
    assert p == pytest.approx(2 * sps.t.sf(abs(t), df), rel=1e-9)
    assert all(math.isnan(x) for x in welch_ttest(A[:1], B))  # one sample: no test
    assert all(math.isnan(x) for x in welch_ttest(np.ones(3), np.ones(4)))  # no variance: no test


def test_bootstrap_interval_matches_scipy():
    low, high = bootstrap_diff_ci(A, B, n_resamples=20_000, seed=1)
    ref = sps.bootstrap(
        (A, B),
        lambda x, y, axis: x.mean(axis) - y.mean(axis),
        vectorized=True,
        n_resamples=20_000,
        method="percentile",
        rng=np.random.default_rng(2),
    ).confidence_interval
    width = ref.high - ref.low
    assert low == pytest.approx(ref.low, abs=0.05 * width) and high == pytest.approx(
        ref.high, abs=0.05 * width
    )
    assert low < A.mean() - B.mean() < high
    assert bootstrap_diff_ci(A, B, seed=3) == bootstrap_diff_ci(A, B, seed=3)  # reproducible
    assert all(math.isnan(x) for x in bootstrap_diff_ci(A[:1], B))
    c = compare(A, B)
    assert (c.n_a, c.n_b) == (7, 9) and c.diff == pytest.approx(A.mean() - B.mean())


def test_standard_error_and_interquartile_mean():
    assert sem(A) == pytest.approx(sps.sem(A), rel=1e-12)
    assert iqm(np.arange(1.0, 9.0)) == pytest.approx(4.5)  # mean of 3, 4, 5, 6
    assert iqm(B) == pytest.approx(sps.trim_mean(B, 0.25))
    assert math.isnan(sem(A[:1])) and math.isnan(iqm(np.array([])))


# ---- replicator dynamics -----------------------------------------------------------------------------


def _points(payoff):
    return {tuple(np.round(r.x, 6)): r for r in egta.rest_points(np.asarray(payoff, float))}


def test_seed_level_testing_refuses_what_pair_level_testing_grants():
    """Algorithm A: half its seeds coordinate, half do not (a pair scores the mean of its seeds' quality);
    B: every seed mediocre. Over the 28 pairs of 8 seeds, A beats B at p < 0.05; but the pairs reuse each
    seed 7 times, and over the 8 seeds (the independent draws) the difference is not significant."""
    quality_a = np.array([0.9, 0.0, 0.6, 0.0, 0.5, 0.1, 0.3, 0.0])
    quality_b = np.array([0.2, 0.25, 0.15, 0.2, 0.25, 0.15, 0.2, 0.2])
    a, b = ((q[:, None] + q[None, :]) / 2 for q in (quality_a, quality_b))
    upper = np.triu_indices(8, k=1)
    pair_level = compare(a[upper], b[upper])
    seed_level = compare(seed_means(a), seed_means(b))
    assert pair_level.n_a == 28 and seed_level.n_a == 8
    assert pair_level.mean_a == pytest.approx(seed_level.mean_a)  # same mean XP, different evidence
    assert pair_level.p < 0.05 < seed_level.p

    # the diagonal (self-play) and missing pairs never enter a seed's cross-play
    m = np.array([[9.0, 1.0, np.nan], [3.0, 9.0, 2.0], [np.nan, 4.0, 9.0]])
    np.testing.assert_allclose(seed_means(m), [1.0, 2.5, 4.0])
    assert np.isnan(seed_means(np.array([[5.0]])))[0]
    with pytest.raises(ValueError, match="square"):
        seed_means(np.zeros((2, 3)))


def test_replicator_rest_points_of_textbook_2x2_games():
    # Hawk-dove (anti-coordination): both pure states repel, the mixed state (1/2, 1/2) attracts.
    hd = _points([[0, 3], [1, 2]])
    assert set(hd) == {(1.0, 0.0), (0.0, 1.0), (0.5, 0.5)}
    assert hd[(0.5, 0.5)].stability == "stable" and hd[(0.5, 0.5)].nash
    assert hd[(1.0, 0.0)].stability == hd[(0.0, 1.0)].stability == "unstable"
    assert not hd[(1.0, 0.0)].nash
    # Coordination game: both conventions attract, the mixed state (1/3, 2/3) separates them.
    co = _points([[2, 0], [0, 1]])
    assert set(co) == {(1.0, 0.0), (0.0, 1.0), (0.333333, 0.666667)}
    assert co[(1.0, 0.0)].stability == co[(0.0, 1.0)].stability == "stable"
    assert co[(0.333333, 0.666667)].stability == "unstable" and co[(0.333333, 0.666667)].nash
    # Along the edge dx1/dt = x1 x2 (3 x2 - (x1 + 2 x2)) for hawk-dove: at (0.25, 0.75) it is +0.1875 x 0.5.
    g = egta.replicator_gradient(np.array([[0, 3], [1, 2.0]]), np.array([0.25, 0.75]))
    assert g == pytest.approx([0.25 * 0.75 * (2.25 - 1.75), -0.25 * 0.75 * (2.25 - 1.75)])
    assert egta.integrate(np.array([[0, 3], [1, 2.0]]), np.array([0.9, 0.1]))[-1] == pytest.approx(
        [0.5, 0.5], abs=1e-3
    )


def test_replicator_rest_points_of_textbook_3x3_games():
    third = (0.333333, 0.333333, 0.333333)
    # Rock-paper-scissors: the three pure states are saddles; the centre is a neutral centre (closed orbits).
    rps = _points([[0, -1, 1], [1, 0, -1], [-1, 1, 0]])
    assert set(rps) == {(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), third}
    assert all(rps[v].stability == "saddle" for v in rps if v != third)
    centre = rps[third]
    assert centre.stability == "non-hyperbolic" and centre.nash
    assert np.allclose(np.real(centre.eigenvalues), 0, atol=1e-9) and np.all(np.imag(centre.eigenvalues) != 0)
    # With wins worth more than losses cost, the centre becomes an attractor.
    good = _points([[0, -1, 2], [2, 0, -1], [-1, 2, 0]])
    assert good[third].stability == "stable" and set(good) == set(rps)
    # A strictly dominant strategy is the one stable rest point; edges hold the mixed points of the pairs.
    dom = _points([[3, 3, 3], [2, 1, 2], [2, 2, 1]])
    stable = [x for x, r in dom.items() if r.stability == "stable"]
    assert stable == [(1.0, 0.0, 0.0)] and dom[(0.0, 0.5, 0.5)].stability == "saddle"
    # Symmetrising averages seat orders: (A + A^T) / 2.
    assert egta.symmetrise(np.array([[1.0, 2.0], [4.0, 3.0]])) == pytest.approx(np.array([[1, 3], [3, 3.0]]))


def test_alpha_rank_ranks_the_dominant_algorithm_first():
    pytest.importorskip("open_spiel")
    payoff = np.array([[100.0, 60, 50], [60, 80, 40], [50, 40, 30]])
    ar = egta.alpha_rank(payoff)
    assert ar.pi is not None and ar.pi.sum() == pytest.approx(1.0)
    assert int(np.argmax(ar.pi)) == 0 and ar.pi[0] > 0.9


# ---- the table and its analyses ------------------------------------------------------------------------


def _table(policies, value, levels=("cramped_room", "coord_ring"), episodes=2, env="overcooked", steps=400):
    """Every pair (self-play once, others in both seat orders) on `levels`; return = value(p, q, level, seat,
    episode) with p the row's policy."""
    cols = {k: [] for k in ("policy_a", "algorithm_a", "seed_a", "policy_b", "algorithm_b", "seed_b", "level",
                            "seat", "episode", "returns", "deliveries", "collisions", "shaped_return", "env",
                            "episode_steps", "actions")}  # fmt: skip
    for i, p in enumerate(policies):
        for q in policies[i:]:
            for level in levels:
                for seat in (0,) if p == q else (0, 1):
                    for ep in range(episodes):
                        r = value(p, q, level, seat, ep)
                        row = (f"{p[0]}{p[1]}", p[0], p[1], f"{q[0]}{q[1]}", q[0], q[1], level, seat, ep, r,
                               r // 20, 1, 0, env, steps, "sampled")  # fmt: skip
                        for k, v in zip(cols, row, strict=True):
                            cols[k].append(v)
    return make_table(cols)


POLICIES = [("cec", 0), ("cec", 1), ("cec", 2), ("ippo", 0), ("ippo", 1)]
BASE = {"cec": 100.0, "ippo": 40.0}


def _value(p, q, level, seat, ep):
    """SP 2 x base; XP the mean of the two bases; +10 on coord_ring; +4 in seat 1; +-2 by episode."""
    r = 2 * BASE[p[0]] if p == q else (BASE[p[0]] + BASE[q[0]]) / 2
    return r + (10 if level == "coord_ring" else 0) + 4 * seat + (2 if ep else -2)


def test_matrices_derive_from_the_long_table():
    t = _table(POLICIES, _value)
    pl = an.pair_level_scores(t)
    cec = an.seed_matrix(pl, "cec")
    assert cec.labels == ("s0", "s1", "s2")
    # SP: 200 + 5 (mean over levels); XP: 100 + 5 + 2 (both seat orders averaged) on every off-diagonal cell.
    assert np.diag(cec.values) == pytest.approx([205.0] * 3)
    assert cec.values[~np.eye(3, dtype=bool)] == pytest.approx([107.0] * 6)
    algos = an.algorithm_matrix(pl)
    assert algos.labels == ("cec", "ippo")
    assert algos.values == pytest.approx(np.array([[107.0, 77.0], [77.0, 47.0]]))
    xp, sp, adhoc = (an.algorithm_samples(pl, k) for k in ("xp", "sp", "adhoc"))
    assert xp["cec"].size == 3 and xp["ippo"].size == 1 and sp["ippo"] == pytest.approx([85.0, 85.0])
    assert adhoc["cec"].size == 6 and adhoc["cec"] == pytest.approx([77.0] * 6)
    levels = {(s.algorithm, s.level): s for s in an.per_level(pl)}
    assert levels[("cec", "coord_ring")].mean == pytest.approx(112.0) and levels[("cec", "coord_ring")].n == 3
    assert levels[("ippo", "cramped_room")].mean == pytest.approx(42.0) and math.isnan(
        levels[("ippo", "cramped_room")].sem
    )
    # Only one level set's levels: the classic set here; a level subset restricts every matrix.
    assert an.level_sets(["generated_001", "cramped_room", "fixed"]) == {
        "classic": ["cramped_room"],
        "fixed": ["fixed"],
        "held-out generated": ["generated_001"],
    }
    only = an.seed_matrix(an.pair_level_scores(t, ["cramped_room"]), "cec")
    assert only.values[0, 0] == pytest.approx(200.0)


def test_seat_orders_weigh_equally_and_orientation_does_not_matter():
    t = _table(POLICIES[:2], _value)
    # Drop one seat-1 episode of the XP pair: episodes are averaged within a seat order first.
    keep = ~((t.seat == 1) & (t.episode == 1) & (t.level == "cramped_room"))
    pl = an.pair_level_scores(t.select(keep), ["cramped_room"])
    assert an.pair_scores(pl)[0, 1] == pytest.approx(((100 + 0) + (104 - 2)) / 2)
    # The same games written from B's side (policy columns swapped, seat flipped) give the same scores.
    flipped = make_table(
        {
            **{f: getattr(t, f) for f in ("level", "episode", "returns", "deliveries", "collisions",
                                          "shaped_return", "env", "episode_steps", "actions")},
            "policy_a": t.policy_b, "algorithm_a": t.algorithm_b, "seed_a": t.seed_b,
            "policy_b": t.policy_a, "algorithm_b": t.algorithm_a, "seed_b": t.seed_a,
            "seat": np.where(t.policy_a == t.policy_b, t.seat, 1 - t.seat),
        }
    )  # fmt: skip
    assert an.pair_scores(an.pair_level_scores(flipped)) == pytest.approx(
        an.pair_scores(an.pair_level_scores(t))
    )


def test_best_response_normalised_score():
    # Two policies, one level, one episode: R(x, x) = 10, R(y, y) = 40, R(x, y) = 20.
    returns = {("x", "x"): 10, ("y", "y"): 40}
    table = _table([("x", 0), ("y", 0)], lambda p, q, *_: returns.get((p[0], q[0]), 20), ("cramped_room",), 1)
    prox = an.br_prox(an.pair_level_scores(table))
    # x with partner y: y's best response is y itself (40): 20 / 40. y with partner x: x's best is y (20): 1.
    assert prox["x"].iqm == pytest.approx(0.5) and prox["y"].iqm == pytest.approx(1.0)
    assert prox["x"].n == prox["y"].n == 1


def test_results_file_round_trip_and_errors(tmp_path: Path):
    t = _table(POLICIES[:2], _value)
    skipped = (SkippedEntry("e3t0", "e3t", 0, "CheckpointError: checkpoint 'x' is missing"),)
    t = make_table({f: getattr(t, f) for f in an_fields()}, skipped)
    back = read_csv(write_csv(t, tmp_path / "r.csv"))
    assert back.skipped == skipped and len(back) == len(t)
    for f in an_fields():
        assert list(getattr(back, f)) == list(getattr(t, f)), f
    (tmp_path / "bad.csv").write_text("policy_a,return\nx,1\n")
    with pytest.raises(ResultsError, match="missing column"):
        read_csv(tmp_path / "bad.csv")
    lines = (tmp_path / "r.csv").read_text().splitlines()
    lines[3] = lines[3].replace(",sampled,", ",sampled,").replace(",overcooked,400,", ",overcooked,four,")
    (tmp_path / "bad2.csv").write_text("\n".join(lines))
    with pytest.raises(ResultsError, match="line 4"):
        read_csv(tmp_path / "bad2.csv")
    (tmp_path / "r.csv.gz").write_bytes(gzip.compress((tmp_path / "r.csv").read_bytes()))
    zipped = read_csv(tmp_path / "r.csv.gz")  # a table committed gzipped reads as it is
    assert [list(getattr(zipped, f)) for f in an_fields()] == [list(getattr(back, f)) for f in an_fields()]
    (tmp_path / "packed").mkdir()
    (tmp_path / "packed" / "results.csv.bz2").write_bytes(bz2.compress((tmp_path / "r.csv").read_bytes()))
    packed = read_csv(stored(tmp_path / "packed" / "results.csv"))  # or bzip2ed, the smaller for large ones
    assert [list(getattr(packed, f)) for f in an_fields()] == [list(getattr(back, f)) for f in an_fields()]
    (tmp_path / "cut.csv.gz").write_bytes((tmp_path / "r.csv.gz").read_bytes()[:-20])
    (tmp_path / "cut.csv.bz2").write_bytes((tmp_path / "packed" / "results.csv.bz2").read_bytes()[:-20])
    (tmp_path / "plain.csv.gz").write_bytes((tmp_path / "r.csv").read_bytes())
    (tmp_path / "plain.csv.bz2").write_bytes((tmp_path / "r.csv").read_bytes())
    for corrupt in ("cut.csv.gz", "plain.csv.gz", "cut.csv.bz2", "plain.csv.bz2"):
        with pytest.raises(ResultsError, match=f"{corrupt} cannot be read as a results file"):
            read_csv(tmp_path / corrupt)
    mixed = type(t).concat([t, _table(POLICIES[:1], _value, env="dual_destination", steps=100)])
    with pytest.raises(ResultsError, match="mix games"):
        an.check_single_env(mixed)
    clash = _table([("cec", 0)], _value)
    clash2 = make_table({**{f: getattr(clash, f) for f in an_fields()}, "policy_a": ["other"] * len(clash)})
    with pytest.raises(ResultsError, match="both cec seed 0"):
        an.policies_of(type(t).concat([clash, clash2]))
    # one seed of a single-kitchen algorithm under two names (its agents of two kitchens, each with the
    # generalists on the held-out kitchens): they never meet, and its pair scores average them
    one = _table([("cec", 0), ("ippo", 0)], lambda *_: 10.0)
    two = _table([("cec", 0), ("ippo", 0)], lambda *_: 30.0)
    renamed = {
        f"policy_{s}": [n.replace("ippo0", "ippo_k0") for n in getattr(two, f"policy_{s}")] for s in "ab"
    }
    two = make_table({**{f: getattr(two, f) for f in an_fields()}, **renamed})
    merged = an.pair_level_scores(type(t).concat([one, two]))
    assert merged.policies == (an.PolicyId("cec", 0), an.PolicyId("ippo", 0))
    assert np.allclose(merged.score, 20.0) and len(merged.score) == 3 * 2  # 3 pairs on 2 levels
    alone = _table([("human_proxy", 0)], lambda *_: 0.0, levels=("coord_ring",))  # plays one level
    on_one = an.pair_level_scores(type(t).concat([one, alone]), ["cramped_room"])
    assert on_one.policies == merged.policies  # the policies of a level set are those that play it


def an_fields():
    return ("policy_a", "algorithm_a", "seed_a", "policy_b", "algorithm_b", "seed_b", "level", "seat",
            "episode", "returns", "deliveries", "collisions", "shaped_return", "env", "episode_steps",
            "actions")  # fmt: skip


def test_report_for_dual_destination_uses_oracle_normalised_scores(tmp_path: Path):
    pols = [("cec", 0), ("cec", 1), ("fcp", 0), ("fcp", 1), ("ippo", 0), ("ippo", 1)]
    base = {"cec": 180.0, "fcp": 120.0, "ippo": 20.0}

    def value(p, q, level, seat, ep):
        return (base[p[0]] + base[q[0]]) / 2 + (5 if p == q else 0) + ep

    t = _table(pols, value, levels=("fixed",), env="dual_destination", steps=100)
    t = make_table({f: getattr(t, f) for f in an_fields()}, [SkippedEntry("broken", "e3t", 2, "corrupt")])
    path = write_report(t, tmp_path / "rep", sources=["x.csv"])
    text = path.read_text()
    assert "normalised score (return / (2 x episode length))" in text
    assert "| fixed | 191 | 0.955 |" in text  # the oracle row: the ceiling of any pair
    assert "| cec | 2 | 0.927 ± 0.000 | 0.903 |" in text  # SP (180 + 5 + 0.5) / 200, XP (180 + 0.5) / 200
    assert "| broken | e3t | 2 | corrupt |" in text
    assert "Meta-game" in text and "| cec 1.000 | stable | yes | yes |" in text
    for name in ("seed_matrices_fixed", "algorithms_fixed", "per_level_fixed", "replicator_fixed"):
        assert (tmp_path / "rep" / f"{name}.png").stat().st_size > 1000


def test_an_algorithm_with_one_seed_has_no_xp_per_level_row(tmp_path: Path):
    """Above `MAX_BARS` levels the XP per level is one row per algorithm: only those with two seeds."""
    levels = tuple(f"generated_{i:03d}" for i in range(13))
    t = _table([*POLICIES, ("fcp", 0)], lambda p, q, *_: 40.0, levels=levels, episodes=1)
    text = write_report(t, tmp_path / "rep").read_text()
    per_level = text.split("### XP per level")[1].split("###")[0]
    assert "| cec | 13 |" in per_level and "| ippo | 13 |" in per_level and "| fcp |" not in per_level


def test_human_proxies_are_their_own_column_not_ad_hoc_partners(tmp_path: Path):
    """`cec report` scores agents with human proxies (`cec humans bc`) beside their cross-play; the proxies
    do not count as ad-hoc partners."""
    base = {**BASE, "human_proxy": 60.0}

    def value(p, q, level, seat, ep):
        return (base[p[0]] + base[q[0]]) / 2 + (10 if level == "coord_ring" else 0) + 4 * seat

    t = _table([*POLICIES, ("human_proxy", 0)], value)
    pl = an.pair_level_scores(t)
    adhoc, human = an.algorithm_samples(pl, "adhoc"), an.algorithm_samples(pl, "human")
    assert adhoc["cec"] == pytest.approx([77.0] * 6)  # with IPPO only: (100 + 40) / 2 + 5 + 2
    assert human["cec"] == pytest.approx([87.0] * 3) and human["ippo"] == pytest.approx([57.0] * 2)
    assert adhoc["human_proxy"].size == 5 and human["human_proxy"].size == 0
    text = write_report(t, tmp_path / "rep").read_text()
    assert "| ad hoc (other algorithms) | with human proxies |" in text
    assert "| cec | 3 | 105.0 ± 0.0 | 107.0 ± 0.0 | 77.0 ± 0.0 | 87.0 ± 0.0 |" in text
    assert "**with human proxies**" in text and "| cec vs ippo | 87.0 vs 57.0 |" in text
    assert "vs human_proxy" not in text  # the proxies are partners, not an algorithm under test
    assert "| human_proxy |" not in text.split("### Meta-game")[1]  # nor a strategy of the meta-game
    assert (tmp_path / "rep" / "replicator_classic.png").is_file()
    assert "E3T ahead, CEC and CEC-Finetune next" in text
    plain = write_report(_table(POLICIES, value), tmp_path / "plain").read_text()
    assert "with human proxies" not in plain


def test_the_report_tests_cross_play_with_the_jackknife_over_seeds(tmp_path: Path):
    """`cec report`'s XP column and XP test come from `crossplay_estimate` / `compare_crossplay` (seeds
    as units, shared pairs counted), never from pairs or per-seed means taken as independent."""
    skill = {("cec", i): v for i, v in enumerate([12.0, 8.0, 20.0, 20.0])}
    skill |= {("ippo", i): v for i, v in enumerate([9.0, 9.0, 9.0, 8.0])}

    def value(p, q, level, seat, ep):
        return skill[p] + skill[q]

    t = _table(list(skill), value, levels=("cramped_room",))
    pl = an.pair_level_scores(t)
    cec, ippo = an.seed_matrix(pl, "cec").values, an.seed_matrix(pl, "ippo").values
    jack = compare_crossplay(cec, ippo)
    naive = compare(seed_means(cec), seed_means(ippo))
    assert naive.p < 0.05 < jack.p  # the per-seed test would call this significant
    text = write_report(t, tmp_path / "rep").read_text()
    est = crossplay_estimate(cec)
    assert f"| {est.mean:.1f} ± {est.se:.1f} |" in text
    row = next(line for line in text.splitlines() if line.startswith("| cec vs ippo |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[6] == f"{jack.p:.2g}" and f"{naive.p:.2g} |" not in row
    # Beside it the exact permutation test over the pooled seeds (one comparison: Holm changes nothing).
    pooled = an.pair_scores(pl)  # the policies in order: cec 0-3, ippo 0-3
    exact = permutation_crossplay(pooled, 4)
    assert cells[7:] == [f"{jack.p:.2g}", f"{exact.p:.2g} ({exact.p_min:.2g})", f"{exact.p:.2g}"]
    assert exact.p_min == pytest.approx(2 / 70)


def test_the_report_holm_corrects_each_table_and_says_why_an_exact_p_is_missing(tmp_path: Path):
    """Three algorithms: three tests in one family, Holm-adjusted together; an algorithm whose seeds never
    met the others' (a hole in the pooled matrix) gets a t-test but no exact p, and the report says why."""
    skill = {("cec", i): 20.0 + 3 * i for i in range(3)}
    skill |= {("ippo", i): 5.0 + i for i in range(3)} | {("fcp", i): 10.0 + 2 * i for i in range(3)}

    def value(p, q, level, seat, ep):
        return skill[p] + skill[q] + ep

    t = _table(list(skill), value, levels=("cramped_room",))
    pl = an.pair_level_scores(t)
    text = write_report(t, tmp_path / "rep").read_text()
    xp = text.split("**XP (other seeds of the same algorithm)**")[1].split("**")[0]
    rows = {r.split("|")[1].strip(): [c.strip() for c in r.strip("|").split("|")] for r in xp.splitlines()
            if r.startswith("| cec vs") or r.startswith("| fcp vs")}  # fmt: skip
    assert set(rows) == {"cec vs fcp", "cec vs ippo", "fcp vs ippo"}
    tests = {k: compare_crossplay(*(an.seed_matrix(pl, a).values for a in k.split(" vs "))) for k in rows}
    adjusted = holm([tests[k].p for k in rows])
    for k, h in zip(rows, adjusted, strict=True):
        assert rows[k][6:8] == [f"{tests[k].p:.2g}", f"{h:.2g}"]
    assert "Exact p '—'" not in text  # every seed met every other: every exact p printed
    # The same agents, but IPPO's seeds never play FCP's: no pooled matrix for that pair.
    keep = ~(np.isin(t.algorithm_a, ["ippo", "fcp"]) & np.isin(t.algorithm_b, ["ippo", "fcp"])
             & (t.algorithm_a != t.algorithm_b))  # fmt: skip
    text = write_report(t.select(keep), tmp_path / "rep2").read_text()
    xp = text.split("**XP (other seeds of the same algorithm)**")[1].split("**")[0]
    row = next(r for r in xp.splitlines() if r.startswith("| fcp vs ippo |"))
    assert row.endswith("| — | — |") and "Exact p '—': the two algorithms' seeds did not all play" in xp


def test_the_same_seeds_trained_on_are_compared_paired_so_what_each_seed_brings_cancels():
    """Seeds of very different skill, each improved by about 6 with more training: the unpaired test
    (seeds of A and B independent) cannot see it through the spread between seeds; the paired one, the
    jackknife of the difference matrix, does; a real difference of 0 is not called one."""
    rng = np.random.default_rng(0)
    skill = np.array([10.0, 30.0, 50.0, 70.0, 20.0])
    before = (skill[:, None] + skill[None, :]) / 2
    noise = rng.normal(0, 0.5, before.shape)
    after = before + 6 + (noise + noise.T) / 2
    paired, unpaired = compare_crossplay_paired(after, before), compare_crossplay(after, before)
    assert paired.diff == pytest.approx(unpaired.diff) and paired.n_a == 5
    assert paired.p < 0.001 and unpaired.p > 0.05
    assert paired.ci_low < 6 < paired.ci_high
    assert compare_crossplay_paired(before + (noise + noise.T) / 2, before).p > 0.05
    with pytest.raises(ValueError, match="differ in shape"):
        compare_crossplay_paired(after, before[:4, :4])


def test_alpha_rank_rows_tied_as_printed_keep_one_order():
    """Masses that print alike (0.000, or 0.500 twice) are ordered by name, whatever the solver's noise."""
    labels = ["d", "b", "a", "c"]
    assert rank_order(np.array([1e-12, 0.5, 3e-13, 0.5 - 1e-12]), labels) == [1, 3, 2, 0]
    assert rank_order(np.array([3e-13, 0.5 - 1e-12, 1e-12, 0.5]), labels) == [1, 3, 2, 0]
    assert rank_order(np.array([0.2, 0.3, 0.1, 0.4]), labels) == [3, 1, 0, 2]
