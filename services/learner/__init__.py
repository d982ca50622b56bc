"""The learner: gathers the actors' rollouts, applies the PPO update, publishes weights and checkpoints."""
