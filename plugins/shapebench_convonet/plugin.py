"""Registers the ``convonet`` method (entry point ``convonet`` of the shapebench distribution)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_methods(register):
    register("convonet", "shapebench_convonet.method:ConvONet")
