"""Registers the ``meshes`` dataset (entry point ``meshes`` of shapebench)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_datasets(register):
    register("meshes", "shapebench_meshes.dataset:MeshFolderDataset")
