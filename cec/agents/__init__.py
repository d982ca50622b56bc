"""Agents: the actor-critic network (paper, reference and small presets)."""

from cec.agents.network import (
    NETWORK_PRESETS,
    ActorCritic,
    LSTMState,
    NetworkConfig,
    init_params,
    network_preset,
    zero_lstm_state,
)

__all__ = [
    "NETWORK_PRESETS",
    "ActorCritic",
    "LSTMState",
    "NetworkConfig",
    "init_params",
    "network_preset",
    "zero_lstm_state",
]
