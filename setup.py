"""Build hook: the wheel carries the built-in configs as package data.

``configs/`` is the repository's user-facing folder (profiles, example sweeps); a wheel or an
sdist-built install has no checkout beside it, so ``build_py`` copies the folder into the package
as ``shapebench/_configs``, where :func:`shapebench.config.config_dirs` finds it through
``importlib.resources``. One copy lives in git; the package's is made at build time. Everything
else about the build is in pyproject.toml.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


class BuildPyWithConfigs(build_py):
    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):  # editable: configs/ is read in the checkout
            return
        target = Path(self.build_lib) / "shapebench" / "_configs"
        shutil.rmtree(target, ignore_errors=True)  # no file removed from configs/ survives
        shutil.copytree(ROOT / "configs", target)


setup(cmdclass={"build_py": BuildPyWithConfigs})
