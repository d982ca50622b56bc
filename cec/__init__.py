"""Cross-Environment Cooperation: train agents that cooperate zero-shot across Overcooked kitchens."""

__version__ = "0.1.0"
