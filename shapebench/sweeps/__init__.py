"""Sweeps: the YAML spec (:mod:`~shapebench.sweeps.spec`), what is left to do
(:mod:`~shapebench.sweeps.plan`), worker processes on this machine
(:mod:`~shapebench.sweeps.launchers`) and cluster jobs through submitit
(:mod:`~shapebench.sweeps.cluster`, :mod:`~shapebench.sweeps.submit`).
"""
