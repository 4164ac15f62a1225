"""Registers ``msc-hier`` and ``msc-hier-noopt`` (entry point ``msc-hier`` of the shapebench
distribution): MSC with a hierarchical encoder, with and without post-encoder optimisation. They
share one training (``checkpoint_family = "msc-hier"``)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_methods(register):
    register("msc-hier", "shapebench_mschier.method:MSCHier")
    register("msc-hier-noopt", "shapebench_mschier.method:MSCHierNoOpt")
