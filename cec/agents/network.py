"""The actor-critic network: CNN encoder, LSTM core with resets at episode starts, separate actor and critic.

One network serves both seats (parameter-shared self-play); each seat feeds its own observation, so the
batch axis below is "env x seat". The `paper` preset is the paper's appendix table; `small` trains in
minutes on a 2-core CPU; `reference` is what the authors' released script builds (no CNN, FC 256, LSTM 128).

Shapes: observations are `[T, B, H, W, C]` (any dtype; cast to float32), resets `bool[T, B]` (True where
the observation is the first of an episode: the LSTM state is zeroed before that step), the LSTM carry
is `LSTMState(c, h)` with `float32[B, lstm]` each. The encoder and heads run on all `T * B` inputs at
once; only the recurrent matmul is inside the time scan.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax.linen.initializers import constant, orthogonal

from cec.config import ConfigError
from cec.envs.overcooked.observation import region_channels

SQRT2 = float(np.sqrt(2.0))
PARTNER_HIDDEN = 64  # width of the partner model's hidden layer


@dataclass(frozen=True)
class NetworkConfig:
    """Layer widths of the actor-critic. Every hidden layer is followed by ReLU.

    Attributes:
        conv_features: filters of each 2x2 convolution (stride 1, SAME padding); empty: no CNN (the
            observation is flattened).
        encoder_features: widths of the fully connected layers after the convolutions.
        lstm_features: LSTM state size (0: no recurrence, the encoder output feeds the heads directly).
        actor_features: hidden widths of the actor head (the output layer has one logit per action).
        critic_features: hidden widths of the critic head (the output layer is one value).
        partner_history: E3T's partner-modelling module (0: none): from the core's features and the
            partner's last `partner_history` actions it predicts the partner's next action; the predicted
            distribution is appended to the actor's input, and an auxiliary loss trains the prediction.
        egocentric: re-centre each observation on the seat's own cell before the encoder
            (`egocentric_view`; channel 0 must mark that cell, as in Overcooked). An allocentric encoder
            must learn every kitchen position separately; centred, what is next to the agent is the same
            input wherever the agent stands, which is what transfers across kitchens.
        cell_features: width of a per-cell embedding (one dense layer on each cell's channels, shared by
            all cells, i.e. a 1x1 convolution) before the convolutions (0: none). Shrinks the flattened
            input of the first dense layer, which dominates the cost of an MLP encoder.
        egocentric_radius: with `egocentric`, how far the frame reaches from the seat's cell: a
            (2r+1) x (2r+1) window (0: the whole frame, (2H-1) x (2W-1), every cell of the grid from any
            cell). A smaller frame shrinks the first dense layer's input with its square, at the cost of
            what lies further away than r cells.
        region_channels: Overcooked only: append to each observation, before everything else, the four
            channels of `region_channels` (the floor each seat can walk to and the cells each can use,
            flood-filled from the view). What the paper's network must infer from the grid, a reachability
            question an MLP answers poorly, given outright; not in the paper (a lever of
            docs/reproduce_overcooked.md).
    """

    conv_features: tuple[int, ...] = (64, 32)
    encoder_features: tuple[int, ...] = (512, 512)
    lstm_features: int = 256
    actor_features: tuple[int, ...] = (256, 192, 128, 64)
    critic_features: tuple[int, ...] = (512, 256, 192, 128)
    partner_history: int = 0
    egocentric: bool = False
    cell_features: int = 0
    egocentric_radius: int = 0
    region_channels: bool = False

    def __post_init__(self) -> None:
        if self.partner_history < 0:
            raise ConfigError(f"partner_history must be >= 0, got {self.partner_history}")
        widths = (*self.conv_features, *self.encoder_features, *self.actor_features, *self.critic_features)
        if any(w <= 0 for w in widths) or self.lstm_features < 0 or self.cell_features < 0:
            raise ConfigError(f"network widths must be positive (lstm_features may be 0), got {self}")
        if self.egocentric_radius < 0 or (self.egocentric_radius and not self.egocentric):
            raise ConfigError(
                f"egocentric_radius must be >= 0 and needs egocentric: true, got {self.egocentric_radius}"
            )
        if self.lstm_features == 0 and not self.encoder_features:
            raise ConfigError("a network without an LSTM needs at least one encoder layer")


#: Named presets per environment. Dual Destination drops the actor's last layer and the critic's last two
#: ("Overcooked only" rows of the paper's table).
NETWORK_PRESETS: dict[str, dict[str, NetworkConfig]] = {
    "paper": {
        "overcooked": NetworkConfig(),
        "dual_destination": NetworkConfig(actor_features=(256, 192, 128), critic_features=(512, 256)),
    },
    "reference": {
        "overcooked": NetworkConfig(
            conv_features=(),
            encoder_features=(256, 256),
            lstm_features=128,
            actor_features=(128, 96, 64, 32),
            critic_features=(256, 128, 96, 64),
        ),
        "dual_destination": NetworkConfig(
            conv_features=(),
            encoder_features=(256, 256),
            lstm_features=128,
            actor_features=(128, 96, 64),
            critic_features=(256, 128),
        ),
    },
    "small": {
        "overcooked": NetworkConfig(
            conv_features=(16,),
            encoder_features=(128,),
            lstm_features=64,
            actor_features=(64,),
            critic_features=(64,),
        ),
        "dual_destination": NetworkConfig(
            conv_features=(),
            encoder_features=(64,),
            lstm_features=32,
            actor_features=(64,),
            critic_features=(64,),
        ),
    },
}


def network_preset(name: str, env: str) -> NetworkConfig:
    """The `NetworkConfig` of preset `name` for environment `env`; `ConfigError` if either is unknown."""
    if name not in NETWORK_PRESETS:
        raise ConfigError(f"unknown network preset {name!r}; choose one of {sorted(NETWORK_PRESETS)}")
    per_env = NETWORK_PRESETS[name]
    if env not in per_env:
        raise ConfigError(f"network preset {name!r} has no variant for env {env!r}; envs: {sorted(per_env)}")
    return per_env[env]


def network_of(preset: str, overrides: NetworkConfig | None, env: str, partner_history: int) -> NetworkConfig:
    """A run's network: the preset for `env` (or the explicit `overrides`) with the partner-modelling
    history of its partner settings (`partner.predict_partner`)."""
    net = overrides or network_preset(preset, env)
    return dataclasses.replace(net, partner_history=partner_history)


class LSTMState(NamedTuple):
    """The recurrent carry: cell `c` and hidden `h`, float32[..., lstm_features] each."""

    c: jax.Array
    h: jax.Array


def zero_lstm_state(batch_shape: tuple[int, ...], features: int) -> LSTMState:
    """Zeros for a batch of LSTM carries (also what an episode start resets to)."""
    zeros = jnp.zeros((*batch_shape, features), jnp.float32)
    return LSTMState(zeros, zeros)


def _dense(features: int, gain: float, name: str) -> nn.Dense:
    return nn.Dense(features, kernel_init=orthogonal(gain), bias_init=constant(0.0), name=name)


class Conv2x2(nn.Module):
    """A 2x2 convolution, stride 1, SAME padding (as `nn.Conv(features, (2, 2), padding="SAME")`), computed
    as one matmul over the four shifted copies of the input (im2col). XLA:CPU's convolution gradients are
    orders of magnitude slower than this for the network's shapes; on every backend it is one big matmul.
    The kernel has `nn.Conv`'s layout [2, 2, in, out]."""

    features: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        kernel = self.param("kernel", orthogonal(SQRT2), (2, 2, x.shape[-1], self.features), jnp.float32)
        bias = self.param("bias", constant(0.0), (self.features,), jnp.float32)
        h, w = x.shape[-3], x.shape[-2]
        padded = jnp.pad(x, [(0, 0)] * (x.ndim - 3) + [(0, 1), (0, 1), (0, 0)])  # SAME for an even kernel
        patches = jnp.concatenate(
            [padded[..., di : di + h, dj : dj + w, :] for di in (0, 1) for dj in (0, 1)], axis=-1
        )
        return patches @ kernel.reshape((-1, self.features)) + bias


def _frame_radii(h: int, w: int, radius: int) -> tuple[int, int]:
    """The frame's reach in rows and columns: `radius`, or 0 for the whole frame (H-1, W-1)."""
    return (radius, radius) if radius else (h - 1, w - 1)


def egocentric_view(x: jax.Array, radius: int = 0) -> jax.Array:
    """[N, H, W, C] grids -> [N, 2a+1, 2b+1, C+1]: each grid shifted so that the cell marked in channel 0
    is at the centre, cut to `radius` cells around it (a = b = radius; 0: a = H-1, b = W-1, the whole grid
    from any cell). The added last channel is 1 on the grid's own cells and 0 on the padding around it, so
    "outside the grid" differs from an empty cell."""
    n, h, w, c = x.shape
    a, b = _frame_radii(h, w, radius)
    at = jnp.argmax(x[..., 0].reshape(n, h * w), axis=-1)
    x = jnp.concatenate([x, jnp.ones((n, h, w, 1), x.dtype)], axis=-1)
    padded = jnp.pad(x, ((0, 0), (a, a), (b, b), (0, 0)))
    window = lambda grid, r, col: jax.lax.dynamic_slice(grid, (r, col, 0), (2 * a + 1, 2 * b + 1, c + 1))  # noqa: E731
    return jax.vmap(window)(padded, at // w, at % w)


def _frame_indices(x: jax.Array, radius: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """For [N, H, W, C] grids with the seat's cell marked in channel 0, where the egocentric frame's cells
    come from: (src int32[N, F] the grid cell (row * W + col) each of the F frame cells shows, inside
    bool[N, F] the frame cell shows a grid cell rather than padding, dst int32[N, H * W] the frame cell
    each grid cell lands on, F where it lies outside a cut frame). Between the grid cells shown and the
    frame cells that show them the map is a bijection."""
    n, h, w, _ = x.shape
    a, b = _frame_radii(h, w, radius)
    at = jnp.argmax(x[..., 0].reshape(n, h * w), axis=-1)
    row, col = (at // w)[:, None, None], (at % w)[:, None, None]
    src_r = jnp.arange(2 * a + 1)[None, :, None] + row - a
    src_c = jnp.arange(2 * b + 1)[None, None, :] + col - b
    inside = (src_r >= 0) & (src_r < h) & (src_c >= 0) & (src_c < w)
    src = jnp.where(inside, src_r * w + src_c, 0).reshape(n, -1)
    dst_r = jnp.arange(h)[None, :, None] - row + a
    dst_c = jnp.arange(w)[None, None, :] - col + b
    shown = (dst_r <= 2 * a) & (dst_r >= 0) & (dst_c <= 2 * b) & (dst_c >= 0)
    dst = jnp.where(shown, dst_r * (2 * b + 1) + dst_c, (2 * a + 1) * (2 * b + 1))
    return src.astype(jnp.int32), inside.reshape(n, -1), dst.reshape(n, -1).astype(jnp.int32)


@jax.custom_vjp
def _to_frame(cells: jax.Array, src: jax.Array, dst: jax.Array) -> jax.Array:
    """[N, H*W, D] per-grid-cell features -> [N, F, D] per-frame-cell features (`src` as `_frame_indices`;
    padding cells get grid cell 0's features, to be replaced by the caller). Its gradient is the inverse
    map, also a gather (`dst`): XLA:CPU's scatter-add, a plain gather's gradient, is many times slower."""
    return jnp.take_along_axis(cells, src[..., None], axis=1)


def _to_frame_fwd(cells: jax.Array, src: jax.Array, dst: jax.Array) -> tuple[jax.Array, jax.Array]:
    return _to_frame(cells, src, dst), dst


def _to_frame_bwd(dst: jax.Array, grad: jax.Array) -> tuple[jax.Array, None, None]:
    # Each grid cell is shown by at most one frame cell, so its gradient is that cell's, gathered (zero for
    # a cell outside a cut frame, whose index is out of range). The caller zeroes the padding cells'
    # gradient (they are replaced), so none of it reaches grid cell 0.
    return jnp.take_along_axis(grad, dst[..., None], axis=1, mode="fill", fill_value=0), None, None


_to_frame.defvjp(_to_frame_fwd, _to_frame_bwd)


class EgocentricCells(nn.Module):
    """`relu(Dense(features)(egocentric_view(x)))` computed on the grid before the shift: the per-cell
    layer runs on the H*W grid cells instead of the (2H-1)(2W-1) frame cells, and the frame is filled with
    `features`-wide embeddings instead of C+1 channels. Same parameters as that Dense (named `cell`, kernel
    [C+1, features]: its last row weighs the frame-membership channel, which is 1 on every grid cell and 0
    on padding, whose embedding is therefore relu(bias)); the same function up to float rounding.

    [N, H, W, C] (any dtype) -> float32[N, 2a+1, 2b+1, features] (a, b as `egocentric_view`'s `radius`).
    """

    features: int
    radius: int = 0

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        n, h, w, c = x.shape
        kernel = self.param("kernel", orthogonal(SQRT2), (c + 1, self.features), jnp.float32)
        bias = self.param("bias", constant(0.0), (self.features,), jnp.float32)
        src, inside, dst = _frame_indices(x, self.radius)
        cells = nn.relu(x.reshape(n, h * w, c).astype(jnp.float32) @ kernel[:c] + (kernel[c] + bias))
        frame = jnp.where(inside[..., None], _to_frame(cells, src, dst), nn.relu(bias))
        a, b = _frame_radii(h, w, self.radius)
        return frame.reshape(n, 2 * a + 1, 2 * b + 1, self.features)


class LSTMCore(nn.Module):
    """An LSTM over time with the state zeroed where `reset` is set (before that step's update).

    The input projection runs on the whole sequence at once; the scan only does `h @ W_h`.
    Gate order i, f, g, o; zero biases.
    """

    features: int

    @nn.compact
    def __call__(self, carry: LSTMState, x: jax.Array, reset: jax.Array) -> tuple[LSTMState, jax.Array]:
        n = self.features
        w_x = self.param("w_x", nn.initializers.lecun_normal(), (x.shape[-1], 4 * n), jnp.float32)
        w_h = self.param("w_h", orthogonal(1.0), (n, 4 * n), jnp.float32)
        bias = self.param("bias", constant(0.0), (4 * n,), jnp.float32)
        x_proj = x @ w_x + bias  # [T, B, 4n]

        def cell(state: LSTMState, inputs: tuple[jax.Array, jax.Array]) -> tuple[LSTMState, jax.Array]:
            xp, r = inputs
            keep = (~r)[:, None].astype(jnp.float32)
            c, h = state.c * keep, state.h * keep
            gates = xp + h @ w_h
            i, f, g, o = jnp.split(gates, 4, axis=-1)
            c = jax.nn.sigmoid(f) * c + jax.nn.sigmoid(i) * jnp.tanh(g)
            h = jax.nn.sigmoid(o) * jnp.tanh(c)
            return LSTMState(c, h), h

        return jax.lax.scan(cell, carry, (x_proj, reset))


class ActorCritic(nn.Module):
    """CNN encoder -> LSTM -> (actor logits, value). See the module docstring for shapes."""

    config: NetworkConfig
    num_actions: int

    @nn.compact
    def __call__(
        self, carry: LSTMState, obs: jax.Array, reset: jax.Array, history: jax.Array | None = None
    ) -> tuple[LSTMState, jax.Array, jax.Array]:
        """Returns (carry after the last step, logits float32[T, B, A], values float32[T, B]).

        `history`: int32[T, B, K] the partner's last K actions (-1: none yet), needed when the config has
        `partner_history` = K > 0; the partner prediction (logits [T, B, A]) is then sown into the
        `intermediates` collection as `partner_logits` (see `forward_partner`).
        """
        cfg = self.config
        t, b = obs.shape[:2]
        x = obs.reshape((t * b, *obs.shape[2:]))
        if cfg.region_channels:
            x = jnp.concatenate([x, region_channels(x).astype(x.dtype)], axis=-1)
        # ENCODER: egocentric view and per-cell embedding, 2x2 convolutions, flatten, fully connected.
        if cfg.egocentric and cfg.cell_features:
            x = EgocentricCells(cfg.cell_features, cfg.egocentric_radius, name="cell")(x)
        else:
            if cfg.egocentric:  # on the raw (uint8) observation: 4x fewer bytes than float32
                x = egocentric_view(x, cfg.egocentric_radius)
            x = x.astype(jnp.float32)
            if cfg.cell_features:
                x = nn.relu(_dense(cfg.cell_features, SQRT2, "cell")(x))
        for i, filters in enumerate(cfg.conv_features):
            x = nn.relu(Conv2x2(filters, name=f"conv{i}")(x))
        x = x.reshape((t * b, -1))
        for i, width in enumerate(cfg.encoder_features):
            x = nn.relu(_dense(width, SQRT2, f"fc{i}")(x))

        # RECURRENT CORE.
        if cfg.lstm_features:
            carry, x = LSTMCore(cfg.lstm_features, name="lstm")(carry, x.reshape((t, b, -1)), reset)
            x = x.reshape((t * b, -1))

        # PARTNER MODEL (E3T): predict the partner's action from the features and its recent actions.
        actor = x
        if cfg.partner_history:
            if history is None:
                raise ValueError("this network models the partner: pass the partner's recent actions")
            past = jax.nn.one_hot(history.reshape((t * b, -1)), self.num_actions)  # -1 -> all zeros
            z = jnp.concatenate([x, past.reshape((t * b, -1))], axis=-1)
            z = nn.relu(_dense(PARTNER_HIDDEN, SQRT2, "partner0")(z))
            partner_logits = _dense(self.num_actions, 0.01, "partner_out")(z)
            self.sow("intermediates", "partner_logits", partner_logits.reshape((t, b, -1)))
            actor = jnp.concatenate([x, jax.lax.stop_gradient(jax.nn.softmax(partner_logits))], axis=-1)

        # HEADS.
        for i, width in enumerate(cfg.actor_features):
            actor = nn.relu(_dense(width, 2.0, f"actor{i}")(actor))
        logits = _dense(self.num_actions, 0.01, "actor_out")(actor)
        critic = x
        for i, width in enumerate(cfg.critic_features):
            critic = nn.relu(_dense(width, 2.0, f"critic{i}")(critic))
        value = _dense(1, 1.0, "critic_out")(critic)
        return carry, logits.reshape((t, b, -1)), value.reshape((t, b))

    def initial_carry(self, batch_shape: tuple[int, ...]) -> LSTMState:
        """Zero LSTM carries for `batch_shape` (a 1-wide dummy carry when the network has no LSTM)."""
        return zero_lstm_state(batch_shape, max(self.config.lstm_features, 1))


def init_params(network: ActorCritic, key: jax.Array, obs_shape: tuple[int, ...]) -> dict:
    """Initial parameters for observations of shape `obs_shape` (one seat, no batch axes)."""
    obs = jnp.zeros((1, 1, *obs_shape), jnp.float32)
    history = empty_history((1, 1), network.config.partner_history)
    variables = network.init(key, network.initial_carry((1,)), obs, jnp.zeros((1, 1), bool), history)
    return {"params": variables["params"]}


def empty_history(batch_shape: tuple[int, ...], k: int) -> jax.Array:
    """int32[*batch_shape, k] of -1: no partner action seen yet."""
    return jnp.full((*batch_shape, k), -1, jnp.int32)


def push_history(history: jax.Array, partner_action: jax.Array) -> jax.Array:
    """The partner-action history [..., K] with `partner_action` [...] appended and the oldest dropped
    (unchanged when K = 0: a network without a partner model)."""
    if history.shape[-1] == 0:
        return history
    return jnp.concatenate([history[..., 1:], partner_action[..., None].astype(jnp.int32)], axis=-1)


def select_action(key: jax.Array, logits: jax.Array, greedy: bool) -> jax.Array:
    """int32 action of the distribution `logits` [A] (log-probabilities will do): its most likely action
    when `greedy`, else a sample drawn with `key`."""
    action = jnp.argmax(logits, axis=-1) if greedy else jax.random.categorical(key, logits)
    return action.astype(jnp.int32)


def forward(
    network: ActorCritic,
    params: Any,
    carry: LSTMState,
    obs: jax.Array,
    reset: jax.Array,
    history: jax.Array | None = None,
) -> tuple[LSTMState, jax.Array, jax.Array]:
    """`network.apply` with its types: (carry after the last step, logits [T, B, A], values [T, B])."""
    out: tuple[LSTMState, jax.Array, jax.Array] = network.apply(params, carry, obs, reset, history)  # type: ignore[assignment]
    return out


def forward_partner(
    network: ActorCritic, params: Any, carry: LSTMState, obs: jax.Array, reset: jax.Array, history: jax.Array
) -> tuple[LSTMState, jax.Array, jax.Array, jax.Array]:
    """`forward`, plus the partner model's predicted partner-action logits [T, B, A]."""
    (carry, logits, value), state = network.apply(
        params, carry, obs, reset, history, mutable=["intermediates"]
    )
    return carry, logits, value, state["intermediates"]["partner_logits"][0]


def frame_embeddable(config: NetworkConfig) -> bool:
    """Whether a network's egocentric frame can be widened by zero weights (`embed_frame`): the frame is
    flattened straight into the first dense layer (no convolution over it)."""
    return config.egocentric and not config.conv_features and bool(config.encoder_features)


def frame_size(config: NetworkConfig, grid: tuple[int, int]) -> tuple[int, int]:
    """The (rows, columns) reach of a network's egocentric frame over `grid` (H, W) cells."""
    return _frame_radii(grid[0], grid[1], config.egocentric_radius)


def embed_frame(params: Any, config: NetworkConfig, radius: int, grid: tuple[int, int]) -> Any:
    """`params` of a `frame_embeddable` network with `config` as parameters of the same network with
    `egocentric_radius` = `radius`, a frame at least as large over `grid` (H, W): the first dense layer's
    weights for the frame cells the smaller frame does not show are zero, so the policy is exactly the same
    (each frame cell's embedding is the same function in both). Lets cross-play batch agents trained with
    a cut frame and agents trained with the whole one through one network."""
    (a, b), (big_a, big_b) = frame_size(config, grid), _frame_radii(grid[0], grid[1], radius)
    if not frame_embeddable(config) or big_a < a or big_b < b:
        raise ValueError(f"cannot embed the frame of {config} into radius {radius} over a {grid} grid")
    if (a, b) == (big_a, big_b):
        return params
    p = dict(params["params"])
    kernel = p["fc0"]["kernel"]
    rows, cols = 2 * a + 1, 2 * b + 1
    cells = kernel.reshape(rows, cols, -1, kernel.shape[-1])  # frame rows, columns, cell width, outputs
    pad = ((big_a - a, big_a - a), (big_b - b, big_b - b), (0, 0), (0, 0))
    p["fc0"] = {**p["fc0"], "kernel": jnp.pad(cells, pad).reshape(-1, kernel.shape[-1])}
    return {"params": p}


def embed_partner_model(params: Any, config: NetworkConfig, target: NetworkConfig, num_actions: int) -> Any:
    """`params` of a network with `config` as parameters of `target` that compute exactly the same policy.

    `target` must equal `config` but for a longer `partner_history`: the added inputs (the partner model's
    prediction in the actor's first layer, older history slots in the partner model) get zero weights, and
    a missing partner model gets zero weights (its prediction then reaches the actor through zero rows).
    Lets cross-play batch E3T agents (with a partner model) and agents without one through one network.
    """
    if dataclasses.replace(config, partner_history=target.partner_history) != target or (
        target.partner_history < config.partner_history
    ):
        raise ValueError(f"cannot embed a network {config} into {target}")
    if config.partner_history == target.partner_history:
        return params
    p = dict(params["params"])
    features = config.lstm_features or config.encoder_features[-1]
    grow = (target.partner_history - config.partner_history) * num_actions
    if config.partner_history:  # older history slots come first in the partner model's input
        kernel = p["partner0"]["kernel"]
        pad = jnp.zeros((grow, kernel.shape[1]), kernel.dtype)
        kernel = jnp.concatenate([kernel[:features], pad, kernel[features:]], axis=0)
        p["partner0"] = {**p["partner0"], "kernel": kernel}
    else:
        first = "actor0" if config.actor_features else "actor_out"
        kernel = p[first]["kernel"]
        p[first] = {
            **p[first],
            "kernel": jnp.concatenate([kernel, jnp.zeros((num_actions, kernel.shape[1]))]),
        }
        inputs = features + target.partner_history * num_actions
        p["partner0"] = {"kernel": jnp.zeros((inputs, PARTNER_HIDDEN)), "bias": jnp.zeros(PARTNER_HIDDEN)}
        p["partner_out"] = {
            "kernel": jnp.zeros((PARTNER_HIDDEN, num_actions)),
            "bias": jnp.zeros(num_actions),
        }
    return {"params": p}
