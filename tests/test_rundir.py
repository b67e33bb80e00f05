"""smol_dsl.rundir: the run directory's format (the metrics schema, its writer and reader,
archive.npz, the docs' tables), and reading run directories: a damaged one is one message
naming the file (and line), exit status 2 from `smol-dsl report`, no traceback and nothing
written; reading one loads neither JAX nor sympy.

The damaged run directories are synthetic (synthetic_runs.write_runs, no training), built
once and copied into tmp_path before each test damages them.
"""

from __future__ import annotations

import csv
import errno
import io
import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from synthetic_runs import LAST_LINE, REPO, SEEDS, loaded_modules, main, refused, write_run, write_runs

from smol_dsl import GEAR, Channel, rundir
from smol_dsl.rundir import (
    METRIC_FIELDS,
    METRICS_SCHEMA,
    REEVALUATION_FIELDS,
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
from smol_dsl.rundir.archive import policy_shapes


@pytest.fixture(scope="module")
def pristine(tmp_path_factory, library) -> Path:
    """Six finished runs (synthetic_runs.write_runs), not to be changed: tests copy them."""
    return write_runs(tmp_path_factory.mktemp("pristine"), library)


@pytest.fixture
def runs(pristine, tmp_path) -> Path:
    """A fresh copy of the run directories, to damage."""
    return Path(shutil.copytree(pristine, tmp_path / "runs"))


def rows_of(schema: MetricsSchema, **extra: float) -> list[dict]:
    common = dict(alpha=1.5, reevaluations=0, coverage=12.5, max_fitness=3.25, qd_score=40.0, non_finite=0, **extra)
    unmeasured = dict.fromkeys(REEVALUATION_FIELDS)
    counts = dict(reevaluated=4, kept=2, moved=1, collided=1, died=0)
    return [
        schema.row(generation=0, phase=0, event="init", evaluations=16, **common, **unmeasured),
        schema.row(generation=1, phase=0, event="train", evaluations=32, **common, **unmeasured),
        schema.row(generation=1, phase=1, event="reevaluate", evaluations=32, **common, **counts),
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
        "reevaluated",
        "kept",
        "moved",
        "collided",
        "died",
    )
    assert METRICS_SCHEMA["alpha"].axis_label == "α" and METRICS_SCHEMA["qd_score"].axis_label == "QD score"


def test_reevaluation_counts_are_on_reevaluate_rows_only_and_add_up(tmp_path):
    path = tmp_path / "metrics.csv"
    rows = rows_of(METRICS_SCHEMA)
    MetricsLog(path, rows)
    assert path.read_text().splitlines()[2].endswith(",0,,,,,")  # a train row: the counts are empty
    assert read_metrics(path) == rows

    lines = path.read_text().splitlines()
    path.write_text("\n".join([*lines[:3], lines[3].replace(",2,1,1,0", ",2,1,1,1")]) + "\n")
    with pytest.raises(RunDirectoryError, match=r"metrics.csv:4: reevaluated 4, kept 2, moved 1, collided 1, died 1"):
        read_metrics(path)
    path.write_text("\n".join([*lines[:2], lines[2][: -len(",,,,,")] + ",4,2,1,1,0", lines[3]]) + "\n")
    with pytest.raises(RunDirectoryError, match=r"metrics.csv:3: reevaluated is '4' on an train row"):
        read_metrics(path)


def test_a_metrics_file_written_before_the_reevaluation_counts_reads(tmp_path):
    """Runs written before the counts were measured lack their columns: read as empty."""
    path = tmp_path / "metrics.csv"
    older = [name for name in METRIC_FIELDS if name not in REEVALUATION_FIELDS]
    rows = rows_of(METRICS_SCHEMA)
    with open(path, "w", newline="") as file:
        writer = csv.DictWriter(file, older, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    assert read_metrics(path) == [{**row, **dict.fromkeys(REEVALUATION_FIELDS)} for row in rows]


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
    policies = policy_shapes("walker2d", config, cells)  # 17 observations -> 64 -> 64 -> 6 actions
    arrays = {
        **{name: rng.normal(size=shape).astype(np.float32) for name, shape in policies.items()},
        "fitnesses": fitnesses,  # (C, 1), as QDax keeps them
        "descriptors": rng.uniform(size=(cells, 2)),
        "centroids": rng.uniform(size=(cells, 2)),
    }
    write_archive(run / rundir.ARCHIVE_FILE, arrays)
    archive = load_archive(run)
    assert archive.fitnesses.shape == (cells,)
    np.testing.assert_array_equal(archive.filled, fitnesses.reshape(-1) > -np.inf)
    elite = archive.elite(archive.best_cell)
    assert elite["params"]["Dense_0"]["kernel"].shape == (17, 64) and elite["params"]["Dense_2"]["bias"].shape == (6,)
    np.testing.assert_array_equal(
        elite["params"]["Dense_0"]["bias"], arrays["genotypes/params/Dense_0/bias"][archive.best_cell]
    )
    checked = read_final_archive(run, config)
    np.testing.assert_array_equal(checked.fitnesses, archive.fitnesses)
    with pytest.raises(ValueError, match="unknown array"):
        write_archive(tmp_path / "x.npz", {**arrays, "extra": np.zeros(1)})
    del arrays["genotypes/params/Dense_2/bias"]  # another network's policies
    write_archive(run / rundir.ARCHIVE_FILE, arrays)
    with pytest.raises(RunDirectoryError, match=r"Dense_2/bias differs\); the archive is of another task or network"):
        read_final_archive(run, config)


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


# ---------------------------------------------------------------------------- damaged runs
def test_truncated_archive_is_refused_before_anything_is_written(runs, tmp_path, capsys):
    for seed in SEEDS:  # whichever run the archives figure would have drawn
        archive = runs / f"walker2d-smol-seed{seed}" / "archive.npz"
        archive.write_bytes(archive.read_bytes()[:500])
    out = tmp_path / "out"
    err = refused(["report", str(runs), "-o", str(out)], capsys, runs / "walker2d-smol-seed0" / "archive.npz")
    assert "3 of the 6 run directories cannot be used" in err and "cut short" in err
    assert not out.exists()


@pytest.mark.parametrize(
    ("damage", "line", "words"),
    [
        (lambda lines: [*lines, "garbage,row"], LAST_LINE + 1, "2 values where the header has 15 columns"),
        (lambda lines: [*lines[:5], "this is not,a row" + "," * 13, *lines[5:]], 6, "is 'this is not', not a whole"),
        (lambda lines: [*lines[:3], lines[3].replace(",train,", ",2.5,"), *lines[4:]], 4, "event is '2.5'"),
        (lambda lines: [*lines[:3], _field(lines[3], 6, "nan"), *lines[4:]], 4, "coverage is 'nan'"),
        (lambda lines: [*lines[:3], _field(lines[3], 8, "inf"), *lines[4:]], 4, "qd_score is 'inf'"),
        (lambda lines: [*lines[:3], _field(lines[3], 2, "-1"), *lines[4:]], 4, "alpha is '-1'"),
        (lambda lines: [*lines[:6], lines[5], *lines[6:]], 7, "repeats line 6"),
        (lambda lines: [*lines, lines[-1]], LAST_LINE + 1, f"repeats line {LAST_LINE}"),
        (lambda lines: lines[:5] + lines[6:], 6, "rows are missing or out of order"),
        (lambda lines: [*lines[:4], lines[5], lines[4], *lines[6:]], 5, "rows are missing or out of order"),
        (lambda lines: lines[:1] + lines[2:], 2, "the first row must be generation 0's init row"),
        (lambda lines: [lines[0].replace(",qd_score", ""), *lines[1:]], 1, "lacks the column(s) qd_score"),
        (lambda lines: [], None, "empty"),
        (lambda lines: lines[:1], None, "a header but no rows"),
    ],
    ids=[
        "garbage-row",
        "text-in-numbers",
        "unknown-event",
        "nan",
        "infinite",
        "negative-alpha",
        "duplicated-row",
        "duplicated-last-row",
        "missing-row",
        "swapped-rows",
        "no-init-row",
        "missing-column",
        "empty-file",
        "header-only",
    ],
)
def test_damaged_metrics_are_refused_with_file_and_line(runs, tmp_path, capsys, damage, line, words):
    metrics = runs / "walker2d-vanilla-seed1" / "metrics.csv"
    lines = damage(metrics.read_text().splitlines())
    metrics.write_text("\n".join(lines) + ("\n" if lines else ""))
    out = tmp_path / "out"
    where = f"{metrics}:{line}:" if line is not None else f"{metrics}:"
    err = refused(["report", str(runs), "-o", str(out)], capsys, where, words)
    assert "move" in err and "rerun" in err  # what to do
    assert not out.exists()


def _field(line: str, index: int, value: str) -> str:
    values = line.split(",")
    values[index] = value
    return ",".join(values)


def test_metrics_that_are_not_text_are_refused(runs, tmp_path, capsys):
    metrics = runs / "walker2d-smol-seed2" / "metrics.csv"
    metrics.write_bytes(metrics.read_bytes()[:200] + bytes(range(128, 256)))
    refused(["report", str(runs), "-o", str(tmp_path / "out")], capsys, metrics, "not a text file")


def test_a_run_that_did_not_finish_is_refused(runs, tmp_path, capsys):
    (runs / "walker2d-smol-seed1" / "archive.npz").unlink()  # metrics complete, no final archive
    err = refused(
        ["report", str(runs), "-o", str(tmp_path / "out")], capsys, runs / "walker2d-smol-seed1" / "archive.npz"
    )
    assert "--resume" in err
    metrics = runs / "walker2d-vanilla-seed0" / "metrics.csv"  # stopped half way
    metrics.write_text("\n".join(metrics.read_text().splitlines()[:8]) + "\n")
    (runs / "walker2d-smol-seed1").rename(tmp_path / "moved-away")
    err = refused(["report", str(runs), "-o", str(tmp_path / "out")], capsys, runs / "walker2d-vanilla-seed0")
    assert "have not finished" in err and "generation 6 of 12" in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("name", "content", "words"),
    [
        ("config.json", None, "missing"),
        ("config.json", "{not json", "not valid JSON"),
        ("config.json", "[1, 2]", "not the run's settings"),
        ("config.json", lambda c: {k: v for k, v in c.items() if k != "batch_size"}, "lacks the setting(s) batch_size"),
        ("config.json", lambda c: {**c, "evaluations": "many"}, 'evaluations is "many", not a whole number'),
        ("config.json", lambda c: {**c, "task": "unicycle"}, "unknown task 'unicycle'"),
        ("config.json", lambda c: {**c, "num_phases": 0}, "num_phases is 0"),
        ("config.json", lambda c: {**c, "colour": "blue"}, "unknown setting(s) colour"),
        ("config.json", lambda c: {**c, "num_phases": 10**15}, "1000000000000000 phases but only 12 generations"),
        ("certificate.json", None, "missing"),
        ("certificate.json", '{"name": "SMOL"}', "tail_start"),
        ("schedule.sched", None, "missing"),
    ],
)
def test_damaged_run_files_are_refused(runs, tmp_path, capsys, name, content, words):
    path = runs / "walker2d-smol-seed0" / name
    if content is None:
        path.unlink()
    elif callable(content):
        path.write_text(json.dumps(content(json.loads(path.read_text()))))
    else:
        path.write_text(content)
    refused(["report", str(runs), "-o", str(tmp_path / "out")], capsys, path, words)
    assert not (tmp_path / "out").exists()


def test_a_schedule_edited_after_the_run_is_refused(runs, tmp_path, capsys):
    """certificate.json holds the digest of the text it proves: a changed number is caught
    even where the edit still verifies and keeps the certificate's fields."""
    path = runs / "walker2d-smol-seed0" / "schedule.sched"
    path.write_text(path.read_text().replace("let child = 1.5", "let child = 1.4"))
    refused(["report", str(runs), "-o", str(tmp_path / "out")], capsys, path, "not the text the run was trained on")
    assert not (tmp_path / "out").exists()


def test_a_run_set_up_before_the_digest_was_recorded_is_still_read(runs):
    path = runs / "walker2d-smol-seed0" / "certificate.json"
    certificate = json.loads(path.read_text())
    del certificate["schedule_sha256"]
    path.write_text(json.dumps(certificate))
    assert read_run(path.parent).schedule == "SMOL"


def test_a_metrics_log_of_another_final_body_is_refused(runs, tmp_path, capsys):
    """metrics.csv's rows in the tail log the final body the schedule proves."""
    path = runs / "walker2d-smol-seed0" / "metrics.csv"
    rows = read_metrics(path)
    rows[-1]["alpha"] = 1.3
    MetricsLog(path, rows)
    refused(["report", str(runs), "-o", str(tmp_path / "out")], capsys, f"{path}:{len(rows) + 1}: alpha is 1.3")


def test_archive_of_the_wrong_shape_or_values_is_refused(runs, pristine, tmp_path, capsys):
    path = runs / "walker2d-vanilla-seed2" / "archive.npz"
    with np.load(path) as data:
        arrays = {name: data[name] for name in data.files}
    np.savez(path, **{name: values[:-1] for name, values in arrays.items()})  # one cell short of the config's 32
    refused(["report", str(runs), "-o", str(tmp_path / "out")], capsys, path, "fitnesses", "(31,)", "(32,)")
    arrays["fitnesses"] = np.full(32, np.nan)
    arrays["filled"] = np.zeros(32, dtype=bool)
    np.savez(path, **arrays)
    refused(["report", str(runs), "-o", str(tmp_path / "out")], capsys, path, "NaN")


def test_archive_header_claiming_a_huge_array_is_refused_before_reading_it(runs, tmp_path, capsys):
    path = runs / "walker2d-smol-seed2" / "archive.npz"
    with np.load(path) as data:
        arrays = {name: data[name] for name in data.files if name != "fitnesses"}
    np.savez(path, **arrays)
    claim = io.BytesIO()
    np.lib.format.write_array_header_1_0(claim, {"descr": "<f8", "fortran_order": False, "shape": (10**12,)})
    with zipfile.ZipFile(path, "a") as bundle:
        bundle.writestr("fitnesses.npy", claim.getvalue() + b"\0" * 64)
    refused(["report", str(runs), "-o", str(tmp_path / "out")], capsys, path, "(1000000000000,)")


def test_unreadable_files_are_refused(runs, tmp_path, capsys):
    metrics = runs / "walker2d-smol-seed0" / "metrics.csv"
    metrics.unlink()
    metrics.mkdir()  # cannot be opened, whoever runs the test (root reads files whatever their mode)
    refused(["report", str(runs), "-o", str(tmp_path / "out")], capsys, metrics, "cannot be read")


def phases_of(directory: Path, damage) -> Path:
    """A run directory's phases.npz (two snapshots of its archive), damaged by `damage(bytes)`."""
    from smol_dsl.rundir.snapshots import END, START, Snapshot, write_snapshots

    archive = load_archive(directory)
    write_snapshots(
        directory, [Snapshot(g, 0, m, archive.fitnesses, archive.descriptors) for g, m in ((0, START), (1, END))]
    )
    path = directory / "phases.npz"
    path.write_bytes(damage(path.read_bytes()))
    return path


@pytest.mark.parametrize(
    ("damage", "words"),
    [
        (lambda data: data[:300], "not a readable phases file (BadZipFile"),
        (lambda data: b"", "not a readable phases file (EOFError"),
        (lambda data: data[:-40], "not a readable phases file"),
        (lambda data: data.replace(b"fitnesses", b"fitnesseX"), "not a readable phases file"),
    ],
    ids=["cut-short", "empty", "end-cut", "array-missing"],
)
def test_a_damaged_phases_file_is_one_message_naming_it(runs, damage, words):
    from smol_dsl.rundir.snapshots import read_snapshots

    path = phases_of(runs / "walker2d-smol-seed0", damage)
    with pytest.raises(RunDirectoryError) as error:
        read_snapshots(path.parent)
    assert str(error.value).startswith(f"{path}: {words}") and "remove it" in str(error.value), error.value


def test_a_report_leaves_a_run_with_a_damaged_phases_file_out_of_its_phase_maps_with_a_note(runs, tmp_path, capsys):
    """Only the phase maps need phases.npz: the damaged run is left out of them, said on stderr,
    in table.md and on the page; the other schedule's phase maps and everything else are written."""
    for seed in SEEDS:  # whichever run the phase maps would have drawn
        phases_of(runs / f"walker2d-smol-seed{seed}", lambda data: data[:300])
        phases_of(runs / f"walker2d-vanilla-seed{seed}", lambda data: data)
    out = tmp_path / "out"
    assert main(["report", str(runs), "--no-gaits", "-o", str(out)]) == 0  # gaits need no phases.npz
    err = capsys.readouterr().err
    damaged = runs / "walker2d-smol-seed1" / "phases.npz"  # SMOL's median run
    assert f"note: the phase maps leave out SMOL's median run (seed 1): {damaged}: " in err, err
    assert "cut short" in err and "Traceback" not in err, err
    assert str(damaged) in (out / "table.md").read_text()
    page = (out / "index.html").read_text()
    assert "phase maps leave out SMOL" in page and 'id="phase-slider"' in page
    assert sorted(p.name for p in out.glob("phase-maps-*.png")) == ["phase-maps-000.png", "phase-maps-001.png"]
    assert (out / "main-results.png").is_file() and (out / "archives.png").is_file()


# ---------------------------------------------------------------------------- a run's body
def test_scheduled_columns_are_in_the_order_of_metrics_csv():
    mass, left_leg = Channel("mass"), Channel("gear", ("left_leg",))
    assert rundir.scheduled_columns((GEAR,)) == ("alpha",)
    assert rundir.scheduled_columns((mass, GEAR)) == ("alpha", "mass")  # plain gear's column comes first
    assert rundir.scheduled_columns((left_leg,)) == ("gear[left_leg]",)
    assert rundir.scheduled_columns((Channel("friction"), mass)) == ("friction", "mass")
    for channels in ((mass, GEAR), (left_leg, mass)):
        names = rundir.metrics_schema(channels).names
        columns = rundir.scheduled_columns(channels)
        assert [name for name in names if name in columns] == list(columns)


def test_the_certificate_names_the_channels_and_the_final_body(tmp_path, library):
    plain = write_run(tmp_path / "plain", library, "human", 0, {"max_fitness": 1.0})
    certificate = rundir.read_certificate(plain / "certificate.json")  # no "channels", no "final_body"
    assert certificate.channels == (GEAR,) and certificate.final_body == {}
    damaged = write_run(tmp_path / "damage", library, "leg-damage", 0, {"max_fitness": 1.0})
    run = read_run(damaged)
    assert run.channels == (Channel("gear", ("left_leg",)),) and run.final_body == {"gear[left_leg]": 0.5}
    assert [row["gear[left_leg]"] for row in run.rows][-1] == 0.5 and run.rows[-1]["alpha"] == 1.0


# ---------------------------------------------------------------------------- import weight
LANGUAGE_AND_TRAINING = ("sympy", "lark", "mpmath", "jax", "brax", "qdax", "flax")
"""What reading a run's config, metrics and archive, or the tasks' ranges, must not load."""


def test_reading_a_run_s_files_loads_neither_the_language_nor_jax(tmp_path, library):
    run = write_run(tmp_path / "run", library, "growth", 0, {"max_fitness": 1.0})
    code = f"""
from pathlib import Path
import smol_dsl.rundir, smol_dsl.tasks
from smol_dsl.rundir import load_archive, read_config, read_final_archive, read_metrics
from smol_dsl.tasks import task_spec
run = Path({str(run)!r})
config = read_config(run / "config.json")
assert read_metrics(run / "metrics.csv", config)[-1]["mass"] > 0
assert read_final_archive(run, config).fitnesses.shape == (config.num_centroids,)
assert load_archive(run).filled.shape == (config.num_centroids,)
task_spec("walker2d").ranges("mjx")
"""
    assert loaded_modules(code, LANGUAGE_AND_TRAINING) == []


def test_reading_a_run_directory_loads_no_jax(tmp_path, library):
    """read_run verifies schedule.sched again (sympy and Lark), but never loads JAX or Brax."""
    run = write_run(tmp_path / "run", library, "growth", 0, {"max_fitness": 1.0})
    code = f"""
from pathlib import Path
from smol_dsl.rundir import load_archive, read_config, read_final_archive, read_metrics, read_run
run = Path({str(run)!r})
record = read_run(run)
config = read_config(run / "config.json")
assert record.finished and record.archive is not None and config == record.config
assert read_metrics(run / "metrics.csv", config) == record.rows and "mass" in record.rows[0]
assert read_final_archive(run, config).fitnesses.shape == (config.num_centroids,)
assert load_archive(run).genotypes["params"]["Dense_0"]["kernel"].shape == (config.num_centroids, 17, 64)
"""
    assert loaded_modules(code, ("jax", "brax", "qdax", "flax")) == []
