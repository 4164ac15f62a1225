"""Registers the ``shapenet55`` dataset (entry point ``pointclouds`` of shapebench)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_datasets(register):
    register("shapenet55", "shapebench_pointclouds.shapenet55:ShapeNet55Dataset")
