"""Empirical game-theoretic analysis of the cross-algorithm meta-game.

Players of the meta-game pick an algorithm; both receive the cross-play score of the two algorithms'
agents (a common-payoff, symmetric game once the seat orders are averaged: `symmetrise`). For a
population with shares x over K algorithms and payoff matrix A (K x K, row = own algorithm):

    replicator dynamics    dx_i/dt = x_i ((A x)_i - x^T A x)

Rest points are found exactly, support by support: on a support S the shares solve A_SS x_S = v 1,
sum(x_S) = 1, x_S > 0. Each is classified by the eigenvalues of the dynamics' Jacobian restricted to the
simplex (its tangent space {v : sum(v) = 0}): `stable` (all real parts < 0: an attractor), `unstable`
(all > 0), `saddle`, or `non-hyperbolic` (some real part 0, e.g. the centre of rock-paper-scissors), and
marked `nash` when no algorithm outside the support earns more than the population average.

Alpha-rank (Omidshafiei et al. 2019) comes from OpenSpiel's `open_spiel.python.egt.alpharank` when it is
installed (`pip install 'cec[egta]'`); otherwise `alpha_rank` says why it is absent.
"""

from __future__ import annotations

import itertools
import math
import warnings
from typing import NamedTuple

import numpy as np


def symmetrise(payoff: np.ndarray) -> np.ndarray:
    """(A + A^T) / 2: the symmetric meta-game payoff of a cross-play matrix (seat effects averaged)."""
    a = np.asarray(payoff, np.float64)
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise ValueError(f"a payoff matrix must be square, got shape {a.shape}")
    return (a + a.T) / 2


def replicator_gradient(payoff: np.ndarray, x: np.ndarray) -> np.ndarray:
    """dx/dt of the replicator dynamics at shares `x` (K,), or at many shares (..., K)."""
    a = np.asarray(payoff, np.float64)
    x = np.asarray(x, np.float64)
    fitness = x @ a.T  # (A x)_i
    average = np.sum(x * fitness, axis=-1, keepdims=True)
    return x * (fitness - average)


def integrate(payoff: np.ndarray, x0: np.ndarray, *, steps: int = 4000, dt: float = 0.05) -> np.ndarray:
    """A trajectory of the replicator dynamics from `x0` (RK4, renormalised to the simplex): (steps+1, K).

    Time is scaled by the payoff range so that `dt` means the same for returns of any magnitude.
    """
    a = np.asarray(payoff, np.float64)
    scale = float(np.ptp(a)) or 1.0
    a = a / scale
    x = np.asarray(x0, np.float64) / np.sum(x0)
    out = [x]
    for _ in range(steps):
        k1 = replicator_gradient(a, x)
        k2 = replicator_gradient(a, x + dt / 2 * k1)
        k3 = replicator_gradient(a, x + dt / 2 * k2)
        k4 = replicator_gradient(a, x + dt * k3)
        x = np.clip(x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4), 0.0, None)
        x = x / x.sum()
        out.append(x)
    return np.stack(out)


class RestPoint(NamedTuple):
    """A rest point of the replicator dynamics.

    Attributes:
        x: float64[K] the shares.
        support: indices of the algorithms with positive share.
        eigenvalues: complex128[K-1] of the Jacobian on the simplex.
        stability: `stable`, `unstable`, `saddle` or `non-hyperbolic`.
        nash: a symmetric Nash equilibrium of the meta-game.
        isolated: False when the support's equations are degenerate (a line or plane of rest points;
            `x` is one of them).
    """

    x: np.ndarray
    support: tuple[int, ...]
    eigenvalues: np.ndarray
    stability: str
    nash: bool
    isolated: bool


def jacobian(payoff: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The K x K Jacobian of the replicator field at `x` (in the ambient coordinates)."""
    a = np.asarray(payoff, np.float64)
    x = np.asarray(x, np.float64)
    fitness = a @ x
    average = x @ fitness
    return np.diag(fitness - average) + x[:, None] * (a - ((a + a.T) @ x)[None, :])


def _tangent_basis(k: int) -> np.ndarray:
    """An orthonormal basis (k, k-1) of {v : sum(v) = 0}."""
    u, _, _ = np.linalg.svd(np.eye(k) - 1.0 / k)  # the projector's leading k-1 singular vectors
    return u[:, : k - 1]


def classify(eigenvalues: np.ndarray, tol: float = 1e-9) -> str:
    re = np.real(eigenvalues)
    if re.size == 0:
        return "stable"
    if np.all(re < -tol):
        return "stable"
    if np.all(re > tol):
        return "unstable"
    if np.any(re > tol) and np.any(re < -tol):
        return "saddle"
    return "non-hyperbolic"


def rest_points(payoff: np.ndarray, *, tol: float = 1e-9) -> list[RestPoint]:
    """Every rest point of the replicator dynamics on the simplex (support enumeration; K up to ~15).

    Payoffs are scaled to a unit range first, so `tol` is relative.
    """
    a = np.asarray(payoff, np.float64)
    k = a.shape[0]
    if a.shape != (k, k):
        raise ValueError(f"a payoff matrix must be square, got shape {a.shape}")
    if k > 15:
        raise ValueError(f"support enumeration over {k} strategies is too large (2^{k} supports)")
    a = a / (float(np.ptp(a)) or 1.0)
    basis = _tangent_basis(k)
    found: list[RestPoint] = []
    for size in range(1, k + 1):
        for support in itertools.combinations(range(k), size):
            s = list(support)
            m = np.zeros((size + 1, size + 1))
            m[:size, :size] = a[np.ix_(s, s)]
            m[:size, size] = -1.0
            m[size, :size] = 1.0
            rhs = np.zeros(size + 1)
            rhs[size] = 1.0
            sol, _, rank, _ = np.linalg.lstsq(m, rhs, rcond=None)
            if np.max(np.abs(m @ sol - rhs)) > 1e-7 or np.any(sol[:size] <= tol):
                continue
            x = np.zeros(k)
            x[s] = sol[:size]
            if any(np.allclose(x, r.x, atol=1e-7) for r in found):
                continue
            eig = np.linalg.eigvals(basis.T @ jacobian(a, x) @ basis)
            fitness = a @ x
            nash = bool(np.all(fitness <= x @ fitness + 1e-7))
            found.append(RestPoint(x, support, eig, classify(eig, tol=1e-7), nash, rank == size + 1))
    return found


class AlphaRank(NamedTuple):
    """Alpha-rank's stationary distribution over algorithms (None with `note` when not computed)."""

    pi: np.ndarray | None
    alpha: float
    m: int
    note: str


def alpha_rank(
    payoff: np.ndarray, *, m: int = 50, alphas: tuple[float, ...] = (10.0, 5.0, 2.0, 1.0)
) -> AlphaRank:
    """Alpha-rank of the symmetric meta-game with OpenSpiel (payoffs min-max scaled to [0, 1]).

    Uses the single-population model with global selection (a mutant's fitness counts play with its own
    kind too, which a common-payoff game needs). The largest `alphas` value whose stationary
    distribution is numerically unique is used and reported.
    """
    try:
        from open_spiel.python.egt import alpharank
    except ImportError as err:
        return AlphaRank(
            None,
            math.nan,
            m,
            f"alpha-rank skipped: OpenSpiel is not installed ({err}); "
            "install it with `pip install 'cec[egta]'`",
        )
    a = symmetrise(payoff)
    span = float(np.ptp(a))
    if span == 0:
        return AlphaRank(np.full(a.shape[0], 1.0 / a.shape[0]), math.nan, m, "all payoffs are equal")
    scaled = (a - a.min()) / span
    for alpha in alphas:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                _, _, pi, _, _ = alpharank.compute(
                    [scaled], m=m, alpha=alpha, use_local_selection_model=False
                )
        except (ValueError, np.linalg.LinAlgError):
            continue
        pi = np.real(np.asarray(pi, np.float64))
        if np.all(np.isfinite(pi)) and np.all(pi > -1e-9):
            pi = np.clip(pi, 0.0, None)
            return AlphaRank(pi / pi.sum(), alpha, m, f"OpenSpiel alpha-rank, alpha={alpha:g}, m={m}")
    return AlphaRank(None, math.nan, m, f"alpha-rank did not converge for alpha in {list(alphas)}")
