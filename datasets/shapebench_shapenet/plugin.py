"""Registers the ``shapenet`` dataset (entry point ``shapenet`` of shapebench)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_datasets(register):
    register("shapenet", "shapebench_shapenet.dataset:ShapeNetDataset")
