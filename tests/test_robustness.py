"""`smol-dsl robustness`: re-scoring finished runs' final archives under perturbations, its
files, its refusals, and what the report adds from them (on real runs, a real browser)."""

from __future__ import annotations

import csv
import io
import math
import shutil

import numpy as np
import pytest
from browser import chromium, visit
from hypothesis import given
from hypothesis import strategies as st
from PIL import Image
from small_runs import CONFIG, cli

import smol_dsl
from smol_dsl.rescoring.perturbations import Perturbations, RobustnessError, check_perturbations
from smol_dsl.rescoring.robustness import reinserted
from smol_dsl.results.robustness import ROBUSTNESS_FILES, robustness_of, robustness_tables
from smol_dsl.rundir import MEDIAN, RobustnessRow, RunDirectoryError, load_archive, read_robustness, read_run
from smol_dsl.rundir.robustness import robustness_csv

SCHEDULES = ("vanilla", "smol")
SEEDS = (0, 1, 2)
CHEAP = ["--body", "gear=0.99,1,1.0056", "--starts", "2"]  # 3 factors, the float path, 2 starts


@pytest.fixture(scope="module")
def robust_sweep(tmp_path_factory):
    """A 2-schedule x 3-seed sweep at the run-level tests' size."""
    from smol_dsl.runner import run_sweep

    out = tmp_path_factory.mktemp("robust") / "sweep"
    run_sweep("walker2d", [smol_dsl.load(name) for name in SCHEDULES], list(SEEDS), CONFIG, out_dir=out)
    return out


@pytest.fixture(scope="module")
def measured(robust_sweep, tmp_path_factory):
    """`smol-dsl robustness` of the sweep into a directory of its own: (directory, rows)."""
    from smol_dsl.cli import main

    out = tmp_path_factory.mktemp("measured")
    assert main(["robustness", str(robust_sweep), "-o", str(out), *CHEAP, "--no-progress"]) == 0
    return out, read_robustness(out / "robustness.csv")


def test_the_command_writes_its_csv_table_and_figure(measured):
    out, rows = measured
    assert sorted(p.name for p in out.iterdir()) == sorted(ROBUSTNESS_FILES)
    runs = {row.directory for row in rows}
    assert len(runs) == len(SCHEDULES) * len(SEEDS)
    per_run = [(row.perturbation, row.sample) for row in rows if row.directory == min(runs)]
    assert per_run == [
        ("body gear", "x0.99"),
        ("body gear", "x1"),
        ("body gear", "x1.0056"),
        ("body gear", MEDIAN),
        ("float path", "batch 32"),
        ("float path", MEDIAN),
        ("starts", "start 0"),
        ("starts", "start 1"),
        ("starts", MEDIAN),
    ]
    for row in rows:  # every elite re-scored is accounted for once
        assert row.kept + row.moved + row.collided + row.died == row.cells
        assert row.coverage == pytest.approx(100 * row.filled / CONFIG.num_centroids)
    table = (out / "robustness.md").read_text()
    assert "U-tests on the robust coverage (body gear)" in table and "Vanilla MAP-Elites" in table and "SMOL" in table
    assert "\\begin{tabular}" in (out / "robustness.tex").read_text()
    figure = Image.open(out / "robustness.png")
    assert figure.size[0] > 500 and np.asarray(figure.convert("L")).std() > 10


def test_the_final_body_in_the_same_program_keeps_every_elite_and_its_fitness(measured, robust_sweep):
    """A body factor of 1 is the archive's own scoring: nothing is chaotic there."""
    _, rows = measured
    for row in rows:
        if row.sample == "x1":
            archive = load_archive(row.directory)
            assert row.cells == int(archive.filled.sum()) > 0
            assert (row.kept, row.moved, row.collided, row.died) == (row.cells, 0, 0, 0)
            assert row.max_fitness == float(archive.fitnesses.max())  # bit for bit


def test_the_csv_lies_beside_the_runs_by_default_and_moves_with_them(robust_sweep, tmp_path, capsys):
    copy = tmp_path / "copy"
    shutil.copytree(robust_sweep, copy)
    code, err = cli(["robustness", str(copy), "--body", "gear=1", "--no-starts", "--no-float-path"], capsys)
    assert code == 0, err
    text = (copy / "robustness.csv").read_text()
    assert str(tmp_path) not in text  # run directories relative to the file
    moved = tmp_path / "moved"
    copy.rename(moved)
    rows = read_robustness(moved / "robustness.csv")
    assert {row.directory for row in rows} == {str(p.resolve()) for p in moved.glob("walker2d-*")}


def test_the_report_adds_robust_coverage_its_u_tests_and_the_figure(measured, robust_sweep, tmp_path, capsys):
    out, _ = measured
    report = tmp_path / "report"
    code, err = cli(
        ["report", str(robust_sweep), "-o", str(report), "--no-gaits", "--robustness", str(out / "robustness.csv")],
        capsys,
    )
    assert code == 0, err
    table = (report / "table.md").read_text()
    assert "U-tests on the robust coverage (body gear)" in table and "elites kept in their cell" in table
    assert "U-tests on the share of elites kept in their cell (starts)" in table
    header = next(csv.reader(io.StringIO((report / "scores.csv").read_text())))
    assert [name for name in header if name.startswith("robust")] == [
        "robust coverage (body gear)",
        "robust coverage (float path)",
        "robust coverage (starts)",
    ]
    page = (report / "index.html").read_text()
    assert 'id="robustness"' in page and 'src="robustness.png"' in page and 'id="robustness-pvalues-0"' in page
    assert (report / "robustness.png").is_file() and (report / "robustness.tex").is_file()


@pytest.mark.skipif(chromium() is None, reason="no Chromium (Debian: apt-get install chromium; .ci/run installs it)")
def test_the_report_page_with_robustness_opens_offline_in_chromium(measured, robust_sweep, tmp_path):
    from smol_dsl.cli import main

    out, _ = measured
    report = tmp_path / "report"
    assert (
        main(
            ["report", str(robust_sweep), "-o", str(report), "--no-gaits", "--robustness", str(out / "robustness.csv")]
        )
        == 0
    )
    seen = visit(report / "index.html")
    assert not [url for url in seen.requests if not url.startswith(report.resolve().as_uri())]
    assert not seen.errors, seen.errors
    sources = {image["src"] for image in seen.images}
    assert "robustness.png" in sources
    assert all(image["complete"] and image["width"] > 0 for image in seen.images), seen.images


def test_the_report_refuses_measurements_of_other_runs(measured, robust_sweep, tmp_path, capsys):
    _, rows = measured
    partial = tmp_path / "partial"
    partial.mkdir()
    kept = [row for row in rows if row.seed != 2]
    (partial / "robustness.csv").write_text(robustness_csv(kept))
    code, err = cli(
        [
            "report",
            str(robust_sweep),
            "-o",
            str(tmp_path / "r"),
            "--no-gaits",
            "--robustness",
            str(partial / "robustness.csv"),
        ],
        capsys,
    )
    assert code == 2 and "has no measurements of" in err and "seed2" in err, err
    assert not (tmp_path / "r").exists()
    code, err = cli(["report", str(robust_sweep), "-o", str(tmp_path / "r"), "--no-gaits", "--robustness"], capsys)
    assert code == 2 and "no robustness.csv in" in err, err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--body", "gear=1e30"], "outside what walker2d's physics takes"),
        (["--body", "mass=0.9"], "has no mass channel"),
        (["--body", "gear=0.9,0.9"], "is given twice"),
        (["--body", "gear=abc"], "the factors are numbers"),
        (["--body", "gear=-1"], "not a finite number above 0"),
        (["--starts", "0"], "must be at least 1"),
        (["--no-body", "--no-starts", "--no-float-path"], "nothing to measure"),
    ],
)
def test_bad_perturbations_are_refused_before_anything_is_measured(robust_sweep, tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    code, err = cli(["robustness", str(robust_sweep), "-o", str(out), *argv], capsys)
    assert code == 2 and message in err.strip().splitlines()[-1], err  # one message, after argparse's usage
    assert not out.exists()


def test_a_run_without_an_archive_is_refused_and_nothing_is_written(robust_sweep, tmp_path, capsys):
    copy = tmp_path / "copy"
    shutil.copytree(robust_sweep, copy)
    (copy / "walker2d-smol-seed1" / "archive.npz").unlink()
    code, err = cli(["robustness", str(copy)], capsys)
    assert code == 2 and "archive.npz: missing" in err, err
    assert not (copy / "robustness.csv").exists()
    code, err = cli(
        [
            "robustness",
            str(robust_sweep),
            "-o",
            str(tmp_path / "first"),
            "--body",
            "gear=1",
            "--no-starts",
            "--no-float-path",
        ],
        capsys,
    )
    assert code == 0
    code, err = cli(["robustness", str(robust_sweep), "-o", str(tmp_path / "first")], capsys)
    assert code == 2 and "--force" in err  # an earlier measurement is kept


def test_the_python_api_refuses_what_the_command_refuses(robust_sweep):
    runs = [read_run(p) for p in sorted(robust_sweep.glob("walker2d-*"))]
    with pytest.raises(RobustnessError, match="has no friction channel"):
        check_perturbations(runs, Perturbations(bodies=(("friction", (0.9,)),)))
    with pytest.raises(RobustnessError, match="starts -1"):
        check_perturbations(runs, Perturbations(starts=-1))
    with pytest.raises(RobustnessError, match="no runs"):
        check_perturbations([], Perturbations())


# -- without training: the file, the insertion and the tables ---------------------------------


rows_strategy = st.builds(
    lambda cells, kept, moved, collided, coverage, fitness, factor, sample: RobustnessRow(
        directory="runs/walker2d-smol-seed0",
        schedule='SMOL, with | and "quotes"',
        seed=3,
        perturbation="body gear",
        sample=sample,
        factor=factor,
        cells=cells + kept + moved + collided,
        filled=kept + moved,
        kept=kept,
        moved=moved,
        collided=collided,
        died=cells,
        coverage=coverage,
        max_fitness=fitness,
    ),
    st.integers(0, 50),
    st.integers(0, 50),
    st.integers(0, 50),
    st.integers(0, 50),
    st.floats(0, 100),
    st.one_of(st.floats(allow_nan=False), st.just(-math.inf)),
    st.one_of(st.just(math.nan), st.floats(0.01, 10)),
    st.sampled_from(["x0.99", MEDIAN, "start 3"]),
)


@given(st.lists(rows_strategy, min_size=1, max_size=5))
def test_robustness_csv_reads_back_what_was_written(tmp_path_factory, rows):
    directory = tmp_path_factory.mktemp("csv")
    (directory / "robustness.csv").write_text(robustness_csv(rows))
    back = read_robustness(directory / "robustness.csv")
    for written, read in zip(rows, back, strict=True):
        assert read.directory == str((directory / written.directory).resolve())
        for name in ("schedule", "seed", "sample", "cells", "kept", "coverage", "max_fitness"):
            assert getattr(read, name) == getattr(written, name)
        assert (math.isnan(read.factor) and math.isnan(written.factor)) or read.factor == written.factor


def test_a_damaged_csv_names_its_file_and_line(tmp_path):
    row = RobustnessRow("r", "SMOL", 0, "starts", "start 0", math.nan, 4, 3, 2, 1, 1, 0, 9.4, 1.0)
    text = robustness_csv([row, row]).splitlines()
    (tmp_path / "robustness.csv").write_text("\n".join([text[0], text[1], text[2].replace(",4,3,2,", ",4,9,2,")]))
    with pytest.raises(RunDirectoryError, match=r"robustness.csv:3: counts that do not add up"):
        read_robustness(tmp_path / "robustness.csv")
    (tmp_path / "robustness.csv").write_text("a,b\n")
    with pytest.raises(RunDirectoryError, match=r"not robustness\.csv's columns"):
        read_robustness(tmp_path / "robustness.csv")


def test_reinsertion_is_qdax_s_collisions_keep_the_best():
    centroids = np.asarray([[0.0, 0.0], [1.0, 1.0], [0.0, 1.0]], dtype=np.float32)
    # cell 0's elite moves to cell 1 and beats cell 1's; cell 2 is empty
    fitnesses = np.asarray([5.0, 3.0, -np.inf], dtype=np.float32)
    descriptors = np.asarray([[0.9, 0.9], [1.0, 1.0], [0.0, 0.0]], dtype=np.float32)
    holder, best = reinserted(centroids, fitnesses, descriptors)
    assert best.tolist() == [-np.inf, 5.0, -np.inf] and holder[1] == 0


def test_the_u_tests_compare_robust_coverage_and_kept_shares_per_perturbation():
    def rows(schedule, seed, coverage, kept):
        common = (f"{schedule}{seed}", schedule, seed, "body gear")
        return [
            RobustnessRow(*common, "x1.1", 1.1, 10, kept, kept, 0, 10 - kept, 0, 3.0 * kept, 1.0),
            RobustnessRow(*common, MEDIAN, math.nan, 10, 5, 5, 0, 5, 0, coverage, 1.0),
        ]

    # SMOL: more robust coverage, Vanilla: a larger share kept
    measured = [r for s in range(5) for r in rows("SMOL", s, 50.0 + s, 2)]
    measured += [r for s in range(5) for r in rows("Vanilla MAP-Elites", s, 10.0 + s, 8)]
    tables = robustness_tables(robustness_of(measured, "walker2d", ["SMOL", "Vanilla MAP-Elites"]))
    coverage, kept = tables["body gear", "robust coverage"], tables["body gear", "kept %"]
    assert coverage.medians == {"SMOL": 52.0, "Vanilla MAP-Elites": 12.0}
    assert coverage.pvalues["Vanilla MAP-Elites"]["SMOL"] == pytest.approx(1 / 252)  # every SMOL run above
    assert kept.medians == {"SMOL": 20.0, "Vanilla MAP-Elites": 80.0}
    assert kept.pvalues["Vanilla MAP-Elites"]["SMOL"] > 0.99


def test_one_scoring_program_serves_every_factor_and_start(measured, robust_sweep):
    """The body and the start are traced inputs: after three factors and two starts, the
    training program has compiled once (and the float path's program once)."""
    from smol_dsl.rescoring.robustness import _float_path_engine, scoring_programs
    from smol_dsl.runner.engine import shared_engine

    runs = [read_run(p) for p in sorted(robust_sweep.glob("walker2d-*"))]
    (program,) = scoring_programs(runs)
    assert len(program.passes) == 1 and program.runs == len(runs)  # the sweep's runs together, as they trained
    engine = shared_engine(
        program.config.task, program.config, program.devices, program.runs_per_step, program.runs, program.channels
    )
    assert engine._scores._cache_size() == 1
    assert _float_path_engine(program)._scores._cache_size() == 1
