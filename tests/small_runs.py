"""The one training size of the run-level tests, as the command line and the library give
it, and helpers for the tests that run, resume and refuse it (in the CLI's own process).

Every test that trains walker2d uses these settings (schedules, seeds, phases and budgets
vary; they change no program), so that a test process builds one engine for them and the
CLI subprocesses load its programs from the session's compilation cache (conftest.py)."""

from __future__ import annotations

import shutil
from pathlib import Path

from smol_dsl.cli import main
from smol_dsl.runner import preset_config
from smol_dsl.runner.engine import shared_task

# the command-line flags and the same settings for the library
FLAGS = ["--evals", "208", "--batch-size", "16", "--phases", "10", "--centroids", "32", "--episode-length", "20"]
SETTINGS = dict(evaluations=208, batch_size=16, num_phases=10, num_centroids=32, episode_length=20)
CONFIG = preset_config("walker2d", "quick", **SETTINGS)
RUN = ["run", "walker2d", "human", *FLAGS, "--no-progress"]
MIXED_SWEEP = ("vanilla", "growth", "leg-damage")  # conftest's mixed_sweep: schedules of different channels


def small_config(task: str = "walker2d", **overrides):
    """The tests' settings for `task`, with fields overridden."""
    return preset_config(task, "quick", **{**SETTINGS, **overrides})


def run_environment(channels=("gear",), physics="spring"):
    """What environment.json records of a `smol-dsl run` in this test process (its devices,
    one run a step), for run directories that tests set up by hand."""
    import jax

    from smol_dsl.rundir import describe_environment, scoring_layout

    return describe_environment(jax.local_devices(), scoring_layout(1, 0, 1, list(channels)), physics)


def small_task(name: str = "walker2d"):
    """The task the runner itself builds for these settings (one per process), so that a
    test's engine and a run's are one."""
    return shared_task(name, CONFIG.episode_length, CONFIG.hidden_layer_sizes)


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
