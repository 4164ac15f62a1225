from shapebench import hookimpl


@hookimpl
def shapebench_register_datasets(register):
    # A "module:Class" path: the class is imported only when the dataset is used, so
    # `shapebench --help` stays fast.
    register("primitives", "shapebench_primitives.dataset:Primitives")
