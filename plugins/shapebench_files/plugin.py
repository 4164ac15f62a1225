"""Registers the ``files`` method (entry point ``files`` of the shapebench distribution)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_methods(register):
    register("files", "shapebench_files.method:FilesMethod")
