"""Registers the ``pcn`` method (entry point ``pcn`` of the shapebench distribution)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_methods(register):
    register("pcn", "shapebench_pcn.method:PCN")
