"""smol_dsl.results: the run directory's format (the metrics schema, its writer and reader,
archive.npz), run figures from plain data, the docs' tables, and reading runs without JAX."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_report import write_run

from smol_dsl import rundir
from smol_dsl.results.figures import save_run_figures
from smol_dsl.rundir import (
    METRIC_FIELDS,
    METRICS_SCHEMA,
    Column,
    MetricsLog,
    MetricsSchema,
    RunDirectoryError,
    atomic_write,
    files_markdown,
    load_archive,
    metrics_row,
    read_final_archive,
    read_metrics,
    read_run,
    write_archive,
)

REPO = Path(__file__).resolve().parent.parent
HEAVY = ("jax", "brax", "qdax", "flax")


def rows_of(schema: MetricsSchema, **extra: float) -> list[dict]:
    common = dict(alpha=1.5, reevaluations=0, coverage=12.5, max_fitness=3.25, qd_score=40.0, non_finite=0, **extra)
    return [
        schema.row(generation=0, phase=0, event="init", evaluations=16, **common),
        schema.row(generation=1, phase=0, event="train", evaluations=32, **common),
        schema.row(generation=1, phase=1, event="reevaluate", evaluations=32, **common),
    ]


def test_the_header_is_the_schema():
    assert METRIC_FIELDS == (
        "generation",
        "phase",
        "alpha",
        "event",
        "evaluations",
        "reevaluations",
        "coverage",
        "max_fitness",
        "qd_score",
        "non_finite",
    )
    assert METRICS_SCHEMA["alpha"].axis_label == "α" and METRICS_SCHEMA["qd_score"].axis_label == "QD score"


def test_a_float_column_added_to_the_schema_flows_through_writer_and_reader(tmp_path):
    schema = MetricsSchema((*METRICS_SCHEMA.columns, Column("mean_fitness", float, "the elites' mean fitness")))
    rows = rows_of(schema, mean_fitness=np.float32(2.5))  # a NumPy (or JAX) scalar becomes a float
    assert type(rows[0]["mean_fitness"]) is float
    path = tmp_path / "metrics.csv"
    log = MetricsLog(path, rows[:1], schema)
    for row in rows[1:]:
        log.append(row)
    assert path.read_text().splitlines()[0] == ",".join(schema.names)
    assert read_metrics(path, schema=schema) == rows
    assert "mean_fitness" not in read_metrics(path)[0]  # the runner's schema ignores the extra column

    lines = path.read_text().splitlines()
    lines[2] = lines[2].replace(",2.5", ",nan")
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(RunDirectoryError, match=r"metrics.csv:3: mean_fitness is 'nan', but must be a finite number"):
        read_metrics(path, schema=schema)
    with pytest.raises(TypeError, match="mean_fitness"):
        schema.row(**rows_of(METRICS_SCHEMA)[0])


def test_metrics_log_starts_as_exactly_the_given_rows(tmp_path):
    path = tmp_path / "metrics.csv"
    rows = rows_of(METRICS_SCHEMA)
    MetricsLog(path, rows)
    MetricsLog(path, rows[:2])  # a resume from an earlier checkpoint drops the later rows
    assert read_metrics(path) == rows[:2]
    MetricsLog(None, rows).append(rows[0])  # no directory: nothing written
    assert metrics_row(**rows[0]) == rows[0]


def test_metrics_log_append_error_names_the_file(tmp_path, monkeypatch):
    path = tmp_path / "metrics.csv"
    log = MetricsLog(path, rows_of(METRICS_SCHEMA)[:1])

    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")  # as a close on a full disk: no file name

    monkeypatch.setattr(rundir.metrics, "open", full_disk, raising=False)
    with pytest.raises(OSError) as caught:
        log.append(rows_of(METRICS_SCHEMA)[1])
    assert caught.value.filename == str(path) and caught.value.errno == errno.ENOSPC


def test_atomic_write_failure_names_the_file_and_leaves_the_old_one(tmp_path):
    path = tmp_path / "config.json"
    path.write_text("old")

    def fails(file):
        file.write(b"half")
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(OSError) as caught:
        atomic_write(path, fails)
    assert caught.value.filename == str(path)
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["config.json"]


def test_archive_round_trip_without_jax(tmp_path, library):
    run = write_run(tmp_path / "run", library, "smol", 0, {"max_fitness": 1.0})
    config = read_run(run).config
    cells = config.num_centroids
    rng = np.random.default_rng(0)
    fitnesses = np.where(rng.uniform(size=(cells, 1)) < 0.5, rng.uniform(size=(cells, 1)), -np.inf)
    arrays = {
        "genotypes/params/Dense_0/kernel": rng.normal(size=(cells, 3, 4)).astype(np.float32),
        "genotypes/params/Dense_0/bias": rng.normal(size=(cells, 4)).astype(np.float32),
        "fitnesses": fitnesses,  # (C, 1), as QDax keeps them
        "descriptors": rng.uniform(size=(cells, 2)),
        "centroids": rng.uniform(size=(cells, 2)),
    }
    write_archive(run / rundir.ARCHIVE_FILE, arrays)
    archive = load_archive(run)
    assert archive.fitnesses.shape == (cells,)
    np.testing.assert_array_equal(archive.filled, fitnesses.reshape(-1) > -np.inf)
    elite = archive.elite(archive.best_cell)
    assert elite["params"]["Dense_0"]["kernel"].shape == (3, 4)
    np.testing.assert_array_equal(
        elite["params"]["Dense_0"]["bias"], arrays["genotypes/params/Dense_0/bias"][archive.best_cell]
    )
    checked = read_final_archive(run, config)
    np.testing.assert_array_equal(checked.fitnesses, archive.fitnesses)
    with pytest.raises(ValueError, match="unknown array"):
        write_archive(tmp_path / "x.npz", {**arrays, "extra": np.zeros(1)})


def test_run_figures_from_the_run_directory(tmp_path, library):
    out = write_run(tmp_path / "run", library, "human", 0, {"max_fitness": 1.0})
    before = sorted(p.name for p in out.iterdir())
    written = save_run_figures(out)
    assert [p.name for p in written] == ["metrics.png", "archive.png"]
    assert all(p.read_bytes().startswith(b"\x89PNG") for p in written)
    assert sorted(p.name for p in out.iterdir()) == sorted([*before, "archive.png", "metrics.png"])  # no temporary file


def test_run_figures_wait_for_the_run_to_finish(tmp_path, library):
    out = write_run(tmp_path / "run", library, "human", 0, {"max_fitness": 1.0}, finished=False)
    with pytest.raises(RunDirectoryError, match="has not finished"):
        save_run_figures(out)


def test_runner_docs_hold_the_format_tables():
    """docs/runner.md's run-directory format section is the schema's own tables."""
    docs = (REPO / "docs" / "runner.md").read_text()
    assert METRICS_SCHEMA.markdown() in docs, METRICS_SCHEMA.markdown()
    assert files_markdown() in docs, files_markdown()


def test_unknown_task_in_config_names_the_file(tmp_path, library):
    run = write_run(tmp_path / "run", library, "smol", 0, {"max_fitness": 1.0})
    config = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**config, "task": "unicycle"}))
    with pytest.raises(RunDirectoryError, match=r"config.json: unknown task 'unicycle'"):
        read_run(run)


def heavy_modules(code: str) -> list[str]:
    """Which of JAX, Brax, QDax and Flax a fresh interpreter has loaded after `code`."""
    probe = f"{code}\nimport sys\nprint(sorted(m for m in {HEAVY!r} if m in sys.modules))"
    result = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])},
    )
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1].replace("'", '"'))


def test_reading_runs_imports_no_jax():
    assert heavy_modules("import smol_dsl.results.report, smol_dsl.rundir, smol_dsl.results.figures") == []


def test_cli_report_imports_no_jax(tmp_path, library):
    for schedule in ("smol", "vanilla"):
        for seed in (0, 1):
            write_run(tmp_path / "runs" / f"{schedule}-{seed}", library, schedule, seed, {"max_fitness": seed})
    code = (
        "from smol_dsl.cli import main\n"
        f"assert main(['report', {str(tmp_path / 'runs')!r}, '-o', {str(tmp_path / 'out')!r}]) == 0"
    )
    assert heavy_modules(code) == []
    assert (tmp_path / "out" / "table.md").is_file()
