"""Registers the ``synthetic`` dataset (entry point ``synthetic`` of shapebench)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_datasets(register):
    register("synthetic", "shapebench_synthetic.dataset:SyntheticDataset")
