"""Registers the ``occnet`` method (entry point ``occnet`` of the shapebench distribution)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_methods(register):
    register("occnet", "shapebench_occnet.method:OccNet")
