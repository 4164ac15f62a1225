"""Registers the ``shapenet55``, ``pcn`` and ``partials`` datasets (entry point
``pointclouds`` of shapebench)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_datasets(register):
    register("shapenet55", "shapebench_pointclouds.shapenet55:ShapeNet55Dataset")
    register("pcn", "shapebench_pointclouds.pcn:PCNDataset")
    register("partials", "shapebench_pointclouds.partials:PartialsDataset")
