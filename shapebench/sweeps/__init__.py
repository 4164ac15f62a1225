"""Sweeps: the YAML spec (:mod:`~shapebench.sweeps.spec`), what is left to do
(:mod:`~shapebench.sweeps.plan`), worker processes on this machine
(:mod:`~shapebench.sweeps.launchers`) and cluster jobs through submitit
(:mod:`~shapebench.sweeps.submit`; :mod:`~shapebench.sweeps.cluster` and
:mod:`~shapebench.sweeps.status` on the login node, :mod:`~shapebench.sweeps.jobs` on the nodes).
"""
