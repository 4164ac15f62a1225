"""Contexts out, completions back: scoring a model that runs outside shapebench's process.

A researcher's model usually lives in its own repository and environment. ``shapebench export``
writes the exact contexts of a set of cells (the ones every built-in method completes) in a
tool-neutral layout with a manifest (:mod:`~shapebench.exchange.export`,
:mod:`~shapebench.exchange.manifest`); the model completes them wherever it runs; the built-in
``files`` method (``plugins/shapebench_files``) reads the completions back as the manifest says,
so they go through the same runner, store, tables, paired tests, pictures and report as every
other row. The guide is docs/byo-completions.md.
"""
