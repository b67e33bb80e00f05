"""Package discovery and the build's commit, the two things pyproject.toml cannot declare.

Every package under smol_dsl/ is found automatically (a new subpackage needs no edit here),
and the schedule library is added as `smol_dsl.schedules`: it lives in the checkout's
top-level schedules/ folder, mapped by `[tool.setuptools.package-dir]` in pyproject.toml,
where `[tool.setuptools.packages.find]` cannot reach it. A package built from a git checkout
(`pip install .`, a wheel) records the commit it was built from in `smol_dsl/BUILD_COMMIT`,
which environment.json reports where no checkout is beside the installed package.
Everything else is in pyproject.toml.
"""

import subprocess
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py

BUILD_COMMIT = "BUILD_COMMIT"


def checkout_commit(root: Path) -> str | None:
    """The checkout's commit, with "+changes" if its tracked files differ from it; None
    outside a git checkout or without git."""
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10)
        status = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    if head.returncode != 0 or status.returncode != 0:
        return None
    return head.stdout.strip() + ("+changes" if status.stdout.strip() else "")


class BuildWithCommit(build_py):
    """build_py that also writes the checkout's commit into the built package (not for an
    editable install, which reads the checkout itself)."""

    def run(self) -> None:
        super().run()
        commit = checkout_commit(Path(__file__).resolve().parent)
        if commit is not None and not getattr(self, "editable_mode", False):
            (Path(self.build_lib) / "smol_dsl" / BUILD_COMMIT).write_text(commit + "\n")


setup(
    packages=[*find_packages(include=["smol_dsl", "smol_dsl.*"]), "smol_dsl.schedules"],
    cmdclass={"build_py": BuildWithCommit},
)
