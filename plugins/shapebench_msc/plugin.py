"""Registers ``msc`` and ``msc-noopt`` (entry point ``msc`` of the shapebench distribution).

Both are rows of the paper's tables: MSC with and without post-encoder latent optimisation. They
share one training (``checkpoint_family = "msc"``).
"""

from shapebench import hookimpl


@hookimpl
def shapebench_register_methods(register):
    register("msc", "shapebench_msc.method:MSC")
    register("msc-noopt", "shapebench_msc.method:MSCNoOpt")
