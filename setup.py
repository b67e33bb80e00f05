"""Package discovery and the build's commit, the two things pyproject.toml cannot declare.

Every package under smol_dsl/ is found automatically (a new subpackage needs no edit here),
and the schedule library is added as `smol_dsl.schedules`: it lives in the checkout's
top-level schedules/ folder, mapped by `[tool.setuptools.package-dir]` in pyproject.toml,
where `[tool.setuptools.packages.find]` cannot reach it. A package built from a git checkout
(`pip install .`, a wheel) records the commit it was built from in `smol_dsl/BUILD_COMMIT`,
which environment.json reports where no checkout is beside the installed package.
Everything else is in pyproject.toml.
"""

import importlib.util
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


def _commit_module():
    """smol_dsl/rundir/commit.py, loaded by its path: it imports nothing of smol-dsl's."""
    spec = importlib.util.spec_from_file_location("smol_dsl_commit", ROOT / "smol_dsl" / "rundir" / "commit.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class BuildWithCommit(build_py):
    """build_py that also writes the checkout's commit into the built package (not for an
    editable install, which reads the checkout itself)."""

    def run(self) -> None:
        super().run()
        commit_module = _commit_module()
        commit = commit_module.checkout_commit(ROOT)
        if commit is not None and not getattr(self, "editable_mode", False):
            (Path(self.build_lib) / "smol_dsl" / commit_module.BUILD_COMMIT).write_text(commit + "\n")


setup(
    packages=[*find_packages(include=["smol_dsl", "smol_dsl.*"]), "smol_dsl.schedules"],
    cmdclass={"build_py": BuildWithCommit},
)
