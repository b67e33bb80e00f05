"""Synthetic run directories, in the runner's format but without training, and the helpers of
the tests that read them (test_rundir), report on them (test_report) and draw them
(test_figures): `write_run` writes one, `write_runs` the set several tests copy and damage."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from smol_dsl import rundir
from smol_dsl.cli import main
from smol_dsl.rundir import ARCHIVE_FILE, METRICS_FILE, MetricsLog, write_archive
from smol_dsl.runner import preset_config
from smol_dsl.tasks import task_spec

REPO = Path(__file__).resolve().parent.parent
SETTINGS = dict(evaluations=16 * 13, batch_size=16, num_phases=10, num_centroids=32, episode_length=20)
"""A synthetic run's settings: 12 generations after the initial population, in 10 phases."""


def write_run(
    directory: Path,
    library: dict,
    schedule: str,
    seed: int,
    final: dict[str, float],
    *,
    task: str = "walker2d",
    finished: bool = True,
    channels: bool = False,
    **overrides: object,
) -> Path:
    """A run directory in the runner's format (written by smol_dsl.rundir's writers) whose
    last row has the given final scores. Its certificate.json holds the schedule's name and
    tail start, and metrics.csv an `alpha` of 1; with `channels`, certificate.json is the
    runner's (the channels and final body too) and metrics.csv has a column per scheduled
    channel, its factor in the row's phase."""
    config = preset_config(task, "quick", seed=seed, **{**SETTINGS, **overrides})
    sched = library[schedule]
    directory.mkdir(parents=True)
    (directory / "config.json").write_text(config.to_json())
    (directory / "schedule.sched").write_text(sched.source)
    certificate = rundir.certificate_record(sched) if channels else {"name": sched.name}
    certificate["tail_start"] = float(sched.tail_start)
    (directory / "certificate.json").write_text(json.dumps(certificate))
    schema = rundir.metrics_schema(sched.channels) if channels else rundir.METRICS_SCHEMA
    bodies = sched.checked_phase_values(config.num_phases) if channels else None
    last = config.generations if finished else config.generations // 2
    rng = np.random.default_rng(seed)
    rows = []
    for generation in range(last + 1):
        phase = config.phase_of_generation(generation) if generation else 0
        row = {
            "generation": generation,
            "phase": phase,
            "alpha": 1.0,
            "event": "train" if generation else "init",
            "evaluations": (generation + 1) * config.batch_size,
            "reevaluations": 0,
            "coverage": rng.uniform(0, 50),
            "max_fitness": rng.uniform(0, 100),
            "qd_score": rng.uniform(0, 1000),
            "non_finite": 0,
        }
        if bodies is not None:
            row.update(rundir.body_columns(sched.channels, bodies[phase]))
        if generation == last:
            row.update(final)
        rows.append(row)
    MetricsLog(directory / METRICS_FILE, rows, schema)
    cells = config.num_centroids
    fitnesses = np.where(rng.uniform(size=cells) < 0.3, rng.uniform(0, 100, cells), -np.inf)
    write_archive(
        directory / ARCHIVE_FILE,
        {
            "genotypes/params/Dense_0/kernel": np.zeros((cells, 2, 2)),
            "fitnesses": fitnesses,
            "descriptors": rng.uniform(size=(cells, task_spec(task).descriptor_size)),
            "centroids": rng.uniform(size=(cells, task_spec(task).descriptor_size)),
        },
    )
    return directory


SCHEDULES = ("smol", "vanilla")
SEEDS = (0, 1, 2)
LAST_LINE = 14  # metrics.csv: the header, then generations 0..12 (SETTINGS: 208 evaluations, batch 16)


def write_runs(root: Path, library: dict) -> Path:
    """Six finished walker2d runs below root, `walker2d-{schedule}-seed{seed}` for SCHEDULES and
    SEEDS, SMOL's final max fitness 5 above vanilla's of the same seed."""
    for schedule in SCHEDULES:
        for seed in SEEDS:
            score = 10.0 * seed + (5 if schedule == "smol" else 0)
            write_run(root / f"walker2d-{schedule}-seed{seed}", library, schedule, seed, {"max_fitness": score})
    return root


def many_schedules(directory: Path, count: int) -> list[Path]:
    """`count` schedule files S1 .. S{count}, each a constant factor and then the tail."""
    paths = []
    for k in range(1, count + 1):
        path = directory / f"s{k}.sched"
        path.write_text(f'name "S{k}"\n0% .. 90%: constant 1.{k:02d}\n90% .. 100%: tail\n')
        paths.append(path)
    return paths


def refused(argv: list[str], capsys, *names: object) -> str:
    """main(argv) exits with status 2 and one message naming every one of names."""
    assert main(argv) == 2
    captured = capsys.readouterr()
    err = captured.err
    assert "Traceback" not in err and "internal error" not in err, err
    assert err.startswith("smol-dsl "), err
    for name in names:
        assert str(name) in err, (name, err)
    return err


def snapshot(directory: Path) -> dict[str, bytes]:
    """Every file of a directory by name, with its bytes (none if it does not exist)."""
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir())} if directory.exists() else {}


LOADED = "loaded modules:"


def loaded_modules(code: str, modules: Sequence[str]) -> list[str]:
    """Which of `modules` a fresh interpreter, this checkout first on its path, has loaded
    after running `code` (which fails the test if it fails)."""
    loaded = f"sorted(m for m in {tuple(modules)!r} if m in sys.modules)"
    probe = f"{code}\nimport json, sys\nprint({LOADED!r}, json.dumps({loaded}))"
    result = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])},
    )
    assert result.returncode == 0, result.stderr
    (line,) = [line for line in result.stdout.splitlines() if line.startswith(LOADED)]
    return json.loads(line.removeprefix(LOADED))
