"""Entry point module: registers the methods by import path, so nothing heavy is imported."""

from shapebench import hookimpl


@hookimpl
def shapebench_register_methods(register):
    register("example-sphere", "shapebench_example.methods:SphereFit")
    register("example-template", "shapebench_example.methods:MeanRadiusTemplate")
    register("example-flaky", "shapebench_example.methods:Flaky")
