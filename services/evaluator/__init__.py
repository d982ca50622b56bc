"""Evaluator: cross-play scoring of new checkpoints against the partner zoo (not built yet)."""
