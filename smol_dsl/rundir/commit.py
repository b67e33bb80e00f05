"""The git commit smol-dsl is built or run from, for environment.json.

Imports nothing of smol-dsl's, so that setup.py can load this file by its path at build
time (when smol-dsl's dependencies may not be installed) and record the commit a package is
built from in `BUILD_COMMIT`, beside the package's modules."""

from __future__ import annotations

import subprocess
from pathlib import Path

BUILD_COMMIT = "BUILD_COMMIT"
"""The file, in the built package `smol_dsl/`, that holds the commit it was built from."""


def checkout_commit(root: Path) -> str | None:
    """The commit of the git checkout at `root`, with "+changes" if its tracked files differ
    from it; None outside a git checkout or without git."""
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10)
        if head.returncode != 0:
            return None
        status = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    if status.returncode != 0:
        return None
    return head.stdout.strip() + ("+changes" if status.stdout.strip() else "")
