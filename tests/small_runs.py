"""A run small enough to compile and train in seconds, as the command line and the library
give it, and helpers for the tests that run, resume and refuse it (in the CLI's own process)."""

from __future__ import annotations

import shutil
from pathlib import Path

from smol_dsl.cli import main
from smol_dsl.runner import preset_config

# the command-line flags and the same settings for the library
FLAGS = ["--evals", "96", "--batch-size", "8", "--phases", "10", "--centroids", "16", "--episode-length", "10"]
CONFIG = preset_config(
    "walker2d", "quick", evaluations=96, batch_size=8, num_phases=10, num_centroids=16, episode_length=10
)
RUN = ["run", "walker2d", "human", *FLAGS, "--no-progress"]


def cli(argv, capsys):
    """main(argv) in this process: (exit status, stderr), and never a traceback."""
    try:
        code = main(argv)
    except SystemExit as exit:  # argparse's own refusals
        code = exit.code
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    return code, err


def copy_of(reference: Path, tmp_path: Path, name: str = "copy") -> Path:
    """A copy of a run directory, to damage or resume."""
    out = tmp_path / name
    shutil.copytree(reference, out)
    return out


def temporaries(directory: Path) -> list[str]:
    """The temporary files left anywhere below a directory."""
    return sorted(p.name for p in directory.rglob("*.tmp"))
