"""Nearest training shape: the no-learning retrieval floor, as a shapebench method plugin."""
