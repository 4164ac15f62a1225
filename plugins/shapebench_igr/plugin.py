"""Registers the ``igr`` method (entry point ``igr`` of the shapebench distribution)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_methods(register):
    register("igr", "shapebench_igr.method:IGR")
