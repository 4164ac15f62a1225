"""An example dataset plugin for shapebench (see docs/plugins.md)."""
