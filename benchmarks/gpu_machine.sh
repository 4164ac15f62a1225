# Sourced by the GPU scripts (gpu_data_scaling.sh, gpu_standard_refs.sh) on a lent machine: the
# carried wheels installed, the tree on PYTHONPATH, and a refusal in seconds when the machine
# cannot prepare data or train. Needs $py (the interpreter) and stamp (a logging function).
# SKIP_WHEELS=1 skips the install (a CPU dry run with the project's .venv).

if [ -z "${SKIP_WHEELS:-}" ] && compgen -G ".whl/*.whl" >/dev/null; then
    stamp "installing carried wheels"
    $py -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
        --target /tmp/site .whl/*.whl || exit 1
    # .gpu/dist holds shapebench's dist-info: its entry points find the built-in plugins.
    export PYTHONPATH=$PWD:$PWD/plugins:$PWD/datasets:$PWD/.gpu/dist:/tmp/site
fi
# Without embree trimesh casts the visibility rays about 1,000 times slower: a lease of 2026-11-29
# spent its whole box preparing 101 files.
$py -c "import embreex" 2>/dev/null || {
    echo "embreex is not importable: carry its wheel in .whl/ (benchmarks/README.md)" >&2
    exit 1
}
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>&1
$py -c "import torch, pytorch_lightning as L, mlflow, trimesh; print('torch', torch.__version__, \
'lightning', L.__version__, 'mlflow', mlflow.__version__, 'cuda', torch.cuda.is_available())" ||
    exit 1
