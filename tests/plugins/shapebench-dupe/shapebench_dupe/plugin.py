from shapebench import hookimpl


@hookimpl
def shapebench_register_methods(register):
    register("gauss", "shapebench_gauss.method:GaussDensification")
