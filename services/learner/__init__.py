"""IPPO learner: trajectory intake, updates, weight publication, checkpoints (not built yet)."""
