"""Registers the ``deepsdf`` method (entry point ``deepsdf`` of the shapebench distribution)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_methods(register):
    register("deepsdf", "shapebench_deepsdf.method:DeepSDF")
