"""Evaluation and planning (placeholder, filled below)."""
