"""Completions from files: scores completions made outside shapebench, as a shapebench method
plugin (see docs/byo-completions.md)."""
