raise ImportError("shapebench_broken needs a library that is not installed")
