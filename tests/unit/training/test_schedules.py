"""`cec.training.schedules`: a value annealed linearly to 0 over env steps, the same traced or not."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import pytest

from cec.training.schedules import anneal_to_zero


@pytest.mark.parametrize(("steps", "want"), [(0, 2.0), (250, 1.5), (500, 1.0), (1000, 0.0), (5000, 0.0)])
def test_the_value_falls_linearly_to_zero_over_the_horizon_and_stays_there(steps: int, want: float) -> None:
    assert float(anneal_to_zero(2.0, jnp.int32(steps), 1000)) == pytest.approx(want)
    traced = jax.jit(lambda s: anneal_to_zero(2.0, s, 1000))
    assert float(traced(jnp.int32(steps))) == pytest.approx(want)


@pytest.mark.parametrize("horizon", [0, -1])
def test_no_horizon_keeps_the_start_value(horizon: int) -> None:
    assert float(anneal_to_zero(0.7, jnp.int32(10**6), horizon)) == pytest.approx(0.7)
