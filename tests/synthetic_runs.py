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
from smol_dsl.qdax.phases import phase_of_generation
from smol_dsl.rundir import ARCHIVE_FILE, METRICS_FILE, MetricsLog, write_archive
from smol_dsl.rundir.archive import policy_shapes
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
    reevaluate: bool = False,
    **overrides: object,
) -> Path:
    """A run directory in the runner's format (written by smol_dsl.rundir's writers) whose
    last row has the given final scores: the runner's certificate.json, metrics.csv with a
    column per scheduled channel (its factor in the row's phase; `alpha` is 1 unless plain
    gear is scheduled), with `reevaluate` a reevaluate row at every phase boundary with random
    counts (the runner's rows; without it, none), and an archive of zero policies of the task's network's shapes
    whose elites score what the last row says (`final_archive`)."""
    config = preset_config(task, "quick", seed=seed, **{**SETTINGS, **overrides})
    sched = library[schedule]
    directory.mkdir(parents=True)
    (directory / "config.json").write_text(config.to_json())
    (directory / "schedule.sched").write_text(sched.source)
    (directory / "certificate.json").write_text(json.dumps(rundir.certificate_record(sched)))
    schema = rundir.metrics_schema(sched.channels)
    bodies = sched.checked_phase_values(config.num_phases)
    last = config.generations if finished else config.generations // 2
    rng = np.random.default_rng(seed)
    fitnesses, scores = final_archive(rng, task, config, final) if finished else (None, {})
    rows = []
    reevaluations = 0
    for generation in range(last + 1):
        phase = phase_of_generation(generation, config.generations, config.num_phases) if generation else 0
        if rows and phase > rows[-1]["phase"] and reevaluate:  # a phase boundary's re-evaluation
            before = int(rng.integers(1, config.num_centroids))
            kept, moved, collided = (int(n) for n in rng.multinomial(before, [0.5, 0.2, 0.2, 0.1])[:3])
            reevaluations += before
            counts = dict(reevaluated=before, kept=kept, moved=moved, collided=collided)
            counts["died"] = before - kept - moved - collided
            rows.append({**rows[-1], "phase": phase, "event": "reevaluate", "reevaluations": reevaluations, **counts})
            rows[-1].update(rundir.body_columns(sched.channels, bodies[phase]))
        row = {
            "generation": generation,
            "phase": phase,
            "alpha": 1.0,
            "event": "train" if generation else "init",
            "evaluations": (generation + 1) * config.batch_size,
            "reevaluations": reevaluations,
            "coverage": rng.uniform(0, 50),
            "max_fitness": rng.uniform(0, 100),
            "qd_score": rng.uniform(0, 1000),
            "non_finite": 0,
            **dict.fromkeys(rundir.REEVALUATION_FIELDS),
        }
        row.update(rundir.body_columns(sched.channels, bodies[phase]))
        if generation == last:
            row.update({**final, **scores})
        rows.append(row)
    MetricsLog(directory / METRICS_FILE, rows, schema)
    cells = config.num_centroids
    if fitnesses is None:
        fitnesses = np.where(rng.uniform(size=cells) < 0.3, rng.uniform(0, 100, cells), -np.inf)
    write_archive(
        directory / ARCHIVE_FILE,
        {
            **{name: np.zeros(shape, np.float32) for name, shape in policy_shapes(task, config, cells).items()},
            "fitnesses": fitnesses,
            "descriptors": rng.uniform(size=(cells, task_spec(task).descriptor_size)),
            "centroids": rng.uniform(size=(cells, task_spec(task).descriptor_size)),
        },
    )
    return directory


def final_archive(rng: np.random.Generator, task: str, config, final: dict[str, float]):
    """Fitnesses of a final archive (-inf in empty cells) whose coverage and max fitness are
    `final`'s where given (a coverage must be a whole number of cells), and the final row's
    scores as QDax computes them from it (float32, the task's QD offset)."""
    cells = config.num_centroids
    if "coverage" in final:
        count = final["coverage"] * cells / 100
        assert count == round(count) and count >= 1, f"coverage {final['coverage']} is no whole number of {cells} cells"
        count = round(count)
    else:
        count = int(rng.integers(1, cells // 2))
    values = rng.uniform(1, 100, count).astype(np.float32)
    if "max_fitness" in final:
        values = (values - values.max() + np.float32(final["max_fitness"])).astype(np.float32)
    fitnesses = np.full(cells, -np.inf, np.float32)
    fitnesses[rng.choice(cells, count, replace=False)] = values
    offset = np.float32(task_spec(task).reward_offset * config.episode_length)
    scores = {
        "coverage": float(np.float32(100) * np.mean(fitnesses > -np.inf, dtype=np.float32)),
        "max_fitness": float(values.max()),
        "qd_score": float(np.sum(values, dtype=np.float32) + offset * np.float32(count)),
    }
    return fitnesses, scores


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
