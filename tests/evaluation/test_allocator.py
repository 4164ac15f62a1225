"""The first completion of a process keeps freed memory for reuse (glibc's thresholds), unless
the user tuned the allocator; each case in a fresh interpreter, since the setting is per process."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or not os.confstr("CS_GNU_LIBC_VERSION"),
    reason="glibc only",
)
@pytest.mark.parametrize(
    "setting",
    [
        None,
        "MALLOC_TRIM_THRESHOLD_=1048576",
        "MALLOC_ARENA_MAX=2",
        "GLIBC_TUNABLES=glibc.malloc.trim_threshold=1048576",
    ],
)
def test_freed_memory_is_kept_unless_the_user_tunes_the_allocator(setting: str | None) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    env.pop("GLIBC_TUNABLES", None)
    if setting:
        key, _, value = setting.partition("=")
        env[key] = value
    code = "from shapebench.evaluation.completion import keep_freed_memory as k; print(k(), k())"
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.split() == (["False", "False"] if setting else ["True", "True"])
