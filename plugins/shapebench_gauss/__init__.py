"""Gauss densification: the paper's simplest baseline, as a shapebench method plugin."""
