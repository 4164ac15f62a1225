"""Registers the ``icl-nuim`` dataset (entry point ``icl-nuim`` of shapebench)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_datasets(register):
    register("icl-nuim", "shapebench_iclnuim.dataset:ICLNUIMDataset")
