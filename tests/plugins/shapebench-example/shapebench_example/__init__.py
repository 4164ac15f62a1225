"""Example third-party methods for shapebench (see docs/plugins.md)."""
