"""Input checks shared by the environments. They run only on eager (concrete) inputs: inside `jit`
nothing can raise, so each env also defines what an out-of-range input does there."""

from __future__ import annotations

from collections.abc import Sequence

import jax
import numpy as np


def is_concrete(*xs: object) -> bool:
    """True when no leaf of `xs` is a JAX tracer (the call is eager, so input errors can be raised)."""
    return not any(isinstance(leaf, jax.core.Tracer) for x in xs for leaf in jax.tree.leaves(x))


def check_actions(actions: jax.Array, names: Sequence[str]) -> None:
    """Raises `ValueError` for eager actions of the wrong shape, dtype or range (`names`: the actions)."""
    if not is_concrete(actions):
        return
    n = len(names)
    a = np.asarray(actions)
    if a.shape[-1:] != (2,):
        raise ValueError(f"actions must have shape (..., 2), one per seat, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"actions must be integers in 0..{n - 1}, got dtype {a.dtype}")
    if a.size and (a.min() < 0 or a.max() >= n):
        raise ValueError(
            f"actions must lie in 0..{n - 1} ({', '.join(names)}), got values "
            f"{np.unique(a[(a < 0) | (a >= n)]).tolist()}; nothing is clipped"
        )
