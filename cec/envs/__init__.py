"""Environments as pure, jittable functions over levels and states."""
