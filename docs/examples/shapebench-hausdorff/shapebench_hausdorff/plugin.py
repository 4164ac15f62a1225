from shapebench import hookimpl


@hookimpl
def shapebench_register_metrics(register):
    register("hausdorff", "shapebench_hausdorff.metric:Hausdorff")
