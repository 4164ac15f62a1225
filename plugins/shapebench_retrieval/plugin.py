"""Registers the ``retrieval`` method (entry point ``retrieval`` of the shapebench distribution)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_methods(register):
    register("retrieval", "shapebench_retrieval.method:Retrieval")
