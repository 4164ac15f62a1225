"""Registers the built-in metrics (entry point ``metrics`` of the shapebench distribution)."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_metrics(register):
    for name, cls in [
        ("chamfer-l2", "ChamferL2"),
        ("chamfer-l1", "ChamferL1"),
        ("chamfer-l2-asym", "ChamferL2Asym"),
        ("chamfer-l1-asym", "ChamferL1Asym"),
        ("chamfer-l1-pointr", "ChamferL1PoinTr"),
    ]:
        register(name, f"shapebench.metrics.chamfer:{cls}")
    register("fscore", "shapebench.metrics.fscore:FScore")
    # On request only (Metric.by_default): the field's other conventions, and the costly EMD.
    register("emd", "shapebench.metrics.emd:EMD")
    register("dcd", "shapebench.metrics.dcd:DCD")
    register("fidelity", "shapebench.metrics.fidelity:Fidelity")
    # Surface metrics of ConvONet: they need the completion's mesh (implicit methods).
    register("normal-consistency", "shapebench.metrics.surface:NormalConsistency")
    register("iou", "shapebench.metrics.surface:IoU")
