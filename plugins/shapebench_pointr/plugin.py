"""Registers the ``pointr`` method (entry point ``pointr`` of the shapebench distribution)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_methods(register):
    register("pointr", "shapebench_pointr.method:PoinTr")
