"""Finding and configuring plugins: entry-point discovery (:mod:`~shapebench.registry.discovery`),
names and overrides to instances (:mod:`~shapebench.registry.resolve`), a leaderboard row's
identity (:mod:`~shapebench.registry.variant`), the code digest in every key
(:mod:`~shapebench.registry.code_digest`), and the plugin checks (:mod:`~shapebench.registry.check`,
:mod:`~shapebench.registry.testing`). Imports :mod:`shapebench.api` and nothing above it.
"""
