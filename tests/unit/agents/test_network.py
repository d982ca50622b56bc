"""The actor-critic network: presets, initialisation, the 2x2 convolution, LSTM resets at episode starts."""

import dataclasses

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cec.agents import ActorCritic, NetworkConfig, init_params, network_preset
from cec.agents.network import Conv2x2, EgocentricCells, egocentric_view
from cec.config import ConfigError


def test_paper_preset_matches_the_papers_table():
    oc = network_preset("paper", "overcooked")
    assert oc.conv_features == (64, 32) and oc.encoder_features == (512, 512) and oc.lstm_features == 256
    assert oc.actor_features == (256, 192, 128, 64) and oc.critic_features == (512, 256, 192, 128)
    dd = network_preset("paper", "dual_destination")
    assert dd.actor_features == (256, 192, 128) and dd.critic_features == (512, 256)
    with pytest.raises(ConfigError, match="unknown network preset"):
        network_preset("huge", "overcooked")


def test_initialisation_is_orthogonal_with_the_tables_gains_and_zero_biases():
    net = ActorCritic(network_preset("paper", "overcooked"), 6)
    params = init_params(net, jax.random.PRNGKey(0), (9, 9, 26))["params"]
    for name, gain in (
        ("fc0", np.sqrt(2)),
        ("actor0", 2.0),
        ("critic3", 2.0),
        ("actor_out", 0.01),
        ("critic_out", 1.0),
    ):
        kernel = np.asarray(params[name]["kernel"])
        sv = np.linalg.svd(kernel, compute_uv=False)
        np.testing.assert_allclose(sv, gain, rtol=1e-4, err_msg=name)
        assert not np.any(params[name]["bias"])
    conv = np.asarray(params["conv0"]["kernel"]).reshape(-1, 64)  # 2x2x26 inputs -> 64 filters
    np.testing.assert_allclose(np.linalg.svd(conv, compute_uv=False), np.sqrt(2), rtol=1e-4)
    assert params["actor_out"]["kernel"].shape == (64, 6)


def test_conv2x2_equals_a_same_padded_flax_convolution():
    x = jax.random.normal(jax.random.PRNGKey(0), (3, 9, 9, 5))
    conv = Conv2x2(7)
    p = conv.init(jax.random.PRNGKey(1), x)
    p = jax.tree.map(lambda a: a + 0.1, p)  # non-zero bias too
    want = nn.Conv(7, (2, 2), padding="SAME").apply(p, x)
    np.testing.assert_allclose(conv.apply(p, x), want, atol=1e-5)


def _run(net, params, obs, reset, carry=None):
    carry = net.initial_carry((obs.shape[1],)) if carry is None else carry
    return net.apply(params, carry, obs, reset)


def test_lstm_state_resets_at_episode_starts():
    net = ActorCritic(network_preset("small", "overcooked"), 6)
    params = init_params(net, jax.random.PRNGKey(0), (9, 9, 26))
    t, b, k = 8, 3, 5
    obs = jax.random.randint(jax.random.PRNGKey(1), (t, b, 9, 9, 26), 0, 2).astype(jnp.uint8)
    reset = jnp.zeros((t, b), bool).at[k, 1].set(True)
    _, logits, values = _run(net, params, obs, reset)
    # Env 1 restarts at step k: its outputs from k on equal a fresh sequence starting there.
    _, fresh_logits, fresh_values = _run(net, params, obs[k:, 1:2], jnp.zeros((t - k, 1), bool))
    np.testing.assert_allclose(logits[k:, 1], fresh_logits[:, 0], atol=1e-5)
    np.testing.assert_allclose(values[k:, 1], fresh_values[:, 0], atol=1e-5)
    # Without the reset the memory carries over (outputs differ), and other envs are unaffected.
    _, no_reset_logits, _ = _run(net, params, obs, jnp.zeros((t, b), bool))
    assert not np.allclose(no_reset_logits[k:, 1], logits[k:, 1])
    np.testing.assert_array_equal(no_reset_logits[:, 0], logits[:, 0])
    # A reset flag zeroes the incoming carry: any carry gives the same outputs at a reset step.
    other = jax.tree.map(lambda x: x + 3.0, net.initial_carry((b,)))
    _, with_other, _ = _run(net, params, obs, jnp.ones((t, b), bool), other)
    _, with_zero, _ = _run(net, params, obs, jnp.ones((t, b), bool))
    np.testing.assert_allclose(with_other, with_zero, atol=1e-6)


def test_network_without_lstm_or_cnn_runs():
    cfg = NetworkConfig(
        conv_features=(), encoder_features=(32,), lstm_features=0, actor_features=(), critic_features=()
    )
    net = ActorCritic(cfg, 5)
    params = init_params(net, jax.random.PRNGKey(0), (5, 5, 4))
    _, logits, values = _run(net, params, jnp.zeros((4, 2, 5, 5, 4)), jnp.zeros((4, 2), bool))
    assert logits.shape == (4, 2, 5) and values.shape == (4, 2)
    with pytest.raises(ConfigError):
        NetworkConfig(lstm_features=0, encoder_features=())


def test_egocentric_view_centres_the_seat_and_marks_the_frame():
    rng = np.random.default_rng(0)
    grids = rng.integers(0, 3, (3, 9, 9, 4)).astype(np.uint8)
    grids[..., 0] = 0
    cells = [(0, 0), (4, 7), (8, 8)]
    for g, (r, c) in zip(grids, cells, strict=True):
        g[r, c, 0] = 1
    view = np.asarray(egocentric_view(jnp.asarray(grids)))
    assert view.shape == (3, 17, 17, 5) and view.dtype == np.uint8
    for g, v, (r, c) in zip(grids, view, cells, strict=True):
        assert v[8, 8, 0] == 1 and v[..., 0].sum() == 1  # the seat's own cell is the centre
        # cell (i, j) of the grid appears at (8 + i - r, 8 + j - c); the padding is zeros, frame channel 0
        np.testing.assert_array_equal(v[8 - r : 17 - r, 8 - c : 17 - c, :4], g)
        assert v[..., 4].sum() == 81 and v[8 - r : 17 - r, 8 - c : 17 - c, 4].all()
        assert v[..., :4].sum() == g.sum()
    # a cut frame is the centre of the whole one: what lies within 3 cells of the seat, padding included
    np.testing.assert_array_equal(egocentric_view(jnp.asarray(grids), radius=3), view[:, 5:12, 5:12])


#: A small egocentric MLP with a 4-wide cell embedding (the recipe's shape at test sizes).
EGO_MLP = NetworkConfig(
    conv_features=(),
    encoder_features=(32,),
    lstm_features=0,
    actor_features=(16,),
    critic_features=(16,),
    egocentric=True,
    cell_features=4,
)


def test_egocentric_network_with_a_cell_embedding_runs():
    cfg = EGO_MLP
    net = ActorCritic(cfg, 6)
    params = init_params(net, jax.random.PRNGKey(0), (9, 9, 3))
    assert params["params"]["cell"]["kernel"].shape == (4, 4)  # 3 channels + the frame channel
    assert params["params"]["fc0"]["kernel"].shape == (17 * 17 * 4, 32)
    obs = jnp.zeros((2, 3, 9, 9, 3)).at[:, :, 2, 2, 0].set(1)
    _, logits, values = _run(net, params, obs, jnp.zeros((2, 3), bool))
    assert logits.shape == (2, 3, 6) and values.shape == (2, 3)
    with pytest.raises(ConfigError):
        NetworkConfig(cell_features=-1)
    with pytest.raises(ConfigError, match="needs egocentric"):  # a cut frame of an allocentric view
        NetworkConfig(egocentric_radius=3)


@pytest.mark.parametrize("radius", [0, 3])
def test_egocentric_cells_equal_the_embedding_of_the_egocentric_view_with_their_gradients(radius):
    """The embed-then-shift layer the recipe trains with is the plain per-cell Dense on the egocentric view
    (same parameters), on the whole 17x17 frame and on a frame cut to 3 cells around the seat (grid cells
    outside it get no gradient): values and gradients equal to float rounding, padding included (a
    positive bias makes the padding's embedding nonzero), for seats in corners, on edges and inside."""
    rng = np.random.default_rng(1)
    grids = rng.integers(0, 2, (6, 9, 9, 5)).astype(np.uint8)
    grids[..., 0] = 0
    for g, (r, c) in zip(grids, [(0, 0), (8, 8), (0, 8), (4, 4), (8, 0), (3, 6)], strict=True):
        g[r, c, 0] = 1
    x = jnp.asarray(grids)
    layer = EgocentricCells(4, radius)
    p = {**layer.init(jax.random.PRNGKey(0), x)["params"], "bias": jnp.asarray([0.3, -0.2, 0.1, 0.5])}
    plain = lambda p: nn.relu(egocentric_view(x, radius).astype(jnp.float32) @ p["kernel"] + p["bias"])  # noqa: E731
    mine = lambda p: layer.apply({"params": p}, x)  # noqa: E731
    np.testing.assert_allclose(mine(p), plain(p), rtol=1e-6, atol=1e-6)
    side = 2 * radius + 1 if radius else 17
    weights = jnp.asarray(rng.normal(size=(6, side, side, 4)), jnp.float32)
    g_mine = jax.grad(lambda p: (mine(p) * weights).sum())(p)
    g_plain = jax.grad(lambda p: (plain(p) * weights).sum())(p)
    for name in ("kernel", "bias"):
        np.testing.assert_allclose(g_mine[name], g_plain[name], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("cell_features", [4, 0])
def test_a_cut_frame_embedded_in_a_larger_one_is_the_same_policy(cell_features):
    """Cross-play batches agents with different egocentric radii through the largest frame: the smaller
    frame's first dense layer padded with zero weights gives the same logits and values, for seats in
    corners, on edges and inside (with and without the per-cell embedding); a frame that does not fit, or
    one a convolution reads, is refused."""
    from cec.agents.network import embed_frame

    rng = np.random.default_rng(2)
    grids = rng.integers(0, 2, (6, 9, 9, 5)).astype(np.uint8)
    grids[..., 0] = 0
    for g, (r, c) in zip(grids, [(0, 0), (8, 8), (0, 8), (4, 4), (8, 0), (3, 6)], strict=True):
        g[r, c, 0] = 1
    obs = jnp.asarray(grids)[None]  # T = 1, B = 6
    reset = jnp.zeros((1, 6), bool)
    base = NetworkConfig(conv_features=(), encoder_features=(32,), lstm_features=0, actor_features=(16,),
                         critic_features=(16,), egocentric=True, cell_features=cell_features)  # fmt: skip
    small = dataclasses.replace(base, egocentric_radius=3)
    net = ActorCritic(small, 6)
    params = init_params(net, jax.random.PRNGKey(3), (9, 9, 5))
    _, logits, values = _run(net, params, obs, reset)
    for radius in (5, 0):  # a larger cut, and the whole 17x17 frame
        big = dataclasses.replace(base, egocentric_radius=radius)
        embedded = embed_frame(params, small, radius, (9, 9))
        _, logits2, values2 = _run(ActorCritic(big, 6), embedded, obs, reset)
        np.testing.assert_allclose(logits2, logits, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(values2, values, rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match="cannot embed"):
        embed_frame(params, small, 2, (9, 9))
    conv = dataclasses.replace(small, conv_features=(8,))
    with pytest.raises(ValueError, match="cannot embed"):
        embed_frame(params, conv, 0, (9, 9))


def test_region_channels_feed_the_flood_filled_regions_to_the_encoder():
    from cec.envs.overcooked import classic_level, reset
    from cec.envs.overcooked.observation import region_channels

    base = dataclasses.replace(EGO_MLP, egocentric_radius=3)
    with_regions = ActorCritic(dataclasses.replace(base, region_channels=True), 6)
    params = init_params(with_regions, jax.random.PRNGKey(0), (9, 9, 26))
    assert params["params"]["cell"]["kernel"].shape == (26 + 4 + 1, 4)  # the four region channels
    obs, _ = reset(jax.random.PRNGKey(0), classic_level("forced_coord"))
    obs = obs[None]  # [T=1, B=2 seats, 9, 9, 26]
    _, logits, values = _run(with_regions, params, obs, jnp.ones((1, 2), bool))
    # The same weights on the observation with the regions appended by hand: the same outputs.
    plain = ActorCritic(base, 6)
    appended = jnp.concatenate([obs, region_channels(obs)], axis=-1)
    _, logits_p, values_p = _run(plain, params, appended, jnp.ones((1, 2), bool))
    np.testing.assert_allclose(logits, logits_p, rtol=1e-6)
    np.testing.assert_allclose(values, values_p, rtol=1e-6)
    # And the regions matter: blank them and the outputs change.
    blank = jnp.concatenate([obs, jnp.zeros_like(region_channels(obs))], axis=-1)
    assert not np.allclose(logits, _run(plain, params, blank, jnp.ones((1, 2), bool))[1])
