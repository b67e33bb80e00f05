"""`smol-dsl robustness`: re-scoring finished runs' final archives under perturbations, its
files, its refusals, and what the report adds from them (on real runs, a real browser)."""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from browser import chromium, visit
from hypothesis import given
from hypothesis import strategies as st
from PIL import Image
from small_runs import CONFIG, cli

import smol_dsl
from smol_dsl.rescoring.perturbations import Perturbations, RobustnessError, check_perturbations
from smol_dsl.rescoring.robustness import median_of_samples, reinserted
from smol_dsl.results.robustness import ROBUSTNESS_FILES, robustness_of
from smol_dsl.results.robustness_tables import robustness_markdown, robustness_tables
from smol_dsl.rundir import MEDIAN, RobustnessRow, RunDirectoryError, load_archive, read_robustness, read_run
from smol_dsl.rundir.robustness import robustness_csv

SCHEDULES = ("vanilla", "smol")
SEEDS = (0, 1, 2)
CHEAP = ["--body", "gear=1", "--body", "gear=0.99,1.0056,1.01", "--starts", "1"]  # 4 factors, the float path, a start
FAMILY = "body gear x0.99-1.01"


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
        ("body gear x1", "x1"),
        ("body gear x1", MEDIAN),
        (FAMILY, "x0.99"),
        (FAMILY, "x1.0056"),
        (FAMILY, "x1.01"),
        (FAMILY, MEDIAN),
        ("float path", "batch 32"),
        ("float path", MEDIAN),
        ("starts", "start 0"),
        ("starts", MEDIAN),
    ]
    for row in rows:  # every elite re-scored is accounted for once
        assert row.kept + row.moved + row.collided + row.died == row.cells
        assert row.coverage == pytest.approx(100 * row.filled / CONFIG.num_centroids)
        assert row.samples == {"body gear x1": 1, FAMILY: 3, "float path": 1, "starts": 1}[row.perturbation]
    table = (out / "robustness.md").read_text()
    assert f"Tests on the robust coverage ({FAMILY})" in table and "Vanilla MAP-Elites" in table and "SMOL" in table
    assert f"Tests on the robust share (robust coverage relative to the cells filled before) ({FAMILY})" in table
    assert "Wilcoxon signed-rank tests, paired by seed" in table and "(Holm " in table
    tex = (out / "robustness.tex").read_text()
    assert "\\begin{tabular}" in tex and "(Holm " in tex
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
    assert f"Tests on the robust coverage ({FAMILY})" in table and "elites kept in their cell" in table
    assert "Tests on the share of elites kept in their cell (starts)" in table and "Holm-adjusted" in table
    header = next(csv.reader(io.StringIO((report / "scores.csv").read_text())))
    assert [name for name in header if name.startswith("robust")] == [
        "robust coverage (body gear x1)",
        f"robust coverage ({FAMILY})",
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
        (["--body", "gear=0.9,1.1"], "over an odd number of factors"),  # a median of two is their midpoint
        (["--body", "gear=0.99,1,1.01"], "x1 is the final body, not a change of it"),
        (["--body", "gear=0.9", "--body", "gear=0.9,0.95,0.99"], "is given twice"),
        (["--starts", "2"], "give an odd number of starts (1 or 3)"),
        (["--starts", "1000000"], "at most 999 other starts"),
        (["--other-physics", "spring"], "trained on spring already"),
        (["--other-physics", "bullet"], "other physics: unknown physics 'bullet'; the physics are spring, mjx"),
        (["--other-physics", "mjx", "--other-physics", "mjx"], "other physics mjx is given twice"),
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


def test_an_output_that_cannot_be_made_is_refused_before_anything_is_measured(robust_sweep, capsys, monkeypatch):
    """Permissions alone do not say it (root may write anywhere but cannot make /proc/x):
    the output is made, written and removed again before measuring, not after."""
    from smol_dsl.rescoring import robustness

    def measured_anyway(*_, **__):
        raise AssertionError("measured before the output was checked")

    monkeypatch.setattr(robustness, "measure_robustness", measured_anyway)
    if Path("/proc/self").is_dir():
        code, err = cli(["robustness", str(robust_sweep), "-o", "/proc/smol-dsl-robustness"], capsys)
        assert code == 2 and "cannot create /proc/smol-dsl-robustness" in err and "give another -o" in err, err


def test_what_cannot_be_held_is_refused_with_its_estimate_and_the_estimate_is_told(
    robust_sweep, tmp_path, capsys, monkeypatch
):
    from smol_dsl.rescoring import perturbations

    monkeypatch.setattr(perturbations, "host_memory_bytes", lambda: 1000)
    code, err = cli(["robustness", str(robust_sweep), "-o", str(tmp_path / "out"), "--starts", "999"], capsys)
    assert code == 2 and "6 runs, 1006 samples each" in err and "would hold more than 50% of" in err, err
    assert "episodes of 20 steps to score" in err and not (tmp_path / "out").exists()


def unfinished_copy(robust_sweep, tmp_path):
    """The sweep with one run not started (its run directory made, nothing trained) and one
    stopped early (its metrics.csv up to the third row, no archive)."""
    copy = tmp_path / "copy"
    shutil.copytree(robust_sweep, copy)
    for name in ("metrics.csv", "archive.npz"):
        (copy / "walker2d-smol-seed1" / name).unlink()
    stopped = copy / "walker2d-vanilla-seed2"
    (stopped / "archive.npz").unlink()
    metrics = stopped / "metrics.csv"
    metrics.write_text("".join(metrics.read_text().splitlines(keepends=True)[:4]))
    return copy


def test_unfinished_runs_are_named_and_the_finished_ones_measured_when_asked(robust_sweep, tmp_path, capsys):
    copy = unfinished_copy(robust_sweep, tmp_path)
    code, err = cli(["robustness", str(copy), "--body", "gear=1", "--no-starts", "--no-float-path"], capsys)
    message = err.strip().splitlines()[-1]
    assert code == 2 and "2 of the 6 runs in" in message, err
    assert "walker2d-smol-seed1 has not started (no metrics.csv)" in message
    assert "walker2d-vanilla-seed2 has not finished (generation" in message
    assert "measure the 4 finished runs with --finished-only" in message
    assert not (copy / "robustness.csv").exists()
    argv = ["robustness", str(copy), "--finished-only", "--body", "gear=1", "--no-starts", "--no-float-path"]
    code, err = cli(argv, capsys)
    assert code == 0, err
    assert "left out: " in err and "has not started" in err and "episodes of 20 steps to score" in err
    rows = read_robustness(copy / "robustness.csv")
    assert len({row.directory for row in rows}) == 4 and all(row.kept == row.cells for row in rows)


def report_with(robust_sweep, tmp_path, capsys, text):
    """`smol-dsl report` of the sweep with robustness.csv's text `text`: (exit status, stderr)."""
    edited = tmp_path / "edited"
    edited.mkdir(exist_ok=True)
    (edited / "robustness.csv").write_text(text)
    argv = ["report", str(robust_sweep), "-o", str(tmp_path / "r"), "--no-gaits"]
    code, err = cli([*argv, "--robustness", str(edited / "robustness.csv")], capsys)
    assert not (tmp_path / "r").exists()
    return code, err.strip().splitlines()[-1]


def test_the_report_refuses_an_edited_or_incomplete_robustness_csv(measured, robust_sweep, tmp_path, capsys):
    out, rows = measured
    lines = (out / "robustness.csv").read_text().splitlines(keepends=True)
    directories = sorted({row.directory for row in rows})
    for deleted in (3, 12):  # a sample of the first run, one of another's
        code, err = report_with(robust_sweep, tmp_path, capsys, "".join(lines[:deleted] + lines[deleted + 1 :]))
        assert code == 2 and "the file is incomplete or was edited" in err and "measure again" in err, err
    elsewhere = lines[:]
    elsewhere[12] = elsewhere[12].replace(lines[12].split(",")[0], "../../etc", 1)
    code, err = report_with(robust_sweep, tmp_path, capsys, "".join(elsewhere))
    assert code == 2 and "the file is incomplete or was edited" in err, err
    another = [row for row in rows if row.directory == directories[0]]  # a whole run more, of no run reported
    extra = [dataclasses.replace(row, directory=str(tmp_path / "etc")) for row in another]
    code, err = report_with(robust_sweep, tmp_path, capsys, robustness_csv(rows + extra))
    assert code == 2 and "which is not among the runs reported on" in err and str(tmp_path / "etc") in err, err
    header, *body = robustness_csv(rows).splitlines(keepends=True)
    older = [
        ",".join(v for n, v in zip(header.strip().split(","), line.split(","), strict=True) if n != "samples")
        for line in [header, *body]
    ]
    code, err = report_with(robust_sweep, tmp_path, capsys, "\n".join(line.strip() for line in older) + "\n")
    assert code == 2 and "written by an older smol-dsl" in err and "measure again" in err, err


def test_measuring_and_checking_are_a_module_of_their_own_without_the_tables_and_figure():
    """results.robustness loads, checks and measures; drawing (matplotlib) and the tests
    (scipy) are robustness_figure's and robustness_tables', loaded only to write them."""
    code = (
        "import sys, smol_dsl.results.robustness as r; "
        "assert not any(m.split('.')[0] in ('matplotlib', 'scipy') for m in sys.modules), sorted(sys.modules); "
        "assert not hasattr(r, 'robustness_figure') and not hasattr(r, 'robustness_tables')"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]


def test_the_python_api_refuses_what_the_command_refuses(robust_sweep):
    runs = [read_run(p) for p in sorted(robust_sweep.glob("walker2d-*"))]
    with pytest.raises(RobustnessError, match="has no friction channel"):
        check_perturbations(runs, Perturbations(bodies=(("friction", (0.9,)),)))
    with pytest.raises(RobustnessError, match="starts -1"):
        check_perturbations(runs, Perturbations(starts=-1))
    with pytest.raises(RobustnessError, match="no runs"):
        check_perturbations([], Perturbations())


# -- without training: the file, the statistic, the insertion and the tables ------------------


def grid_rows(runs, perturbations, sample_counts):
    """A whole robustness.csv grid: `runs` (directory, schedule, seed), each with every
    perturbation's samples and its median, each row its counts from `sample_counts`."""
    counts = iter(sample_counts)
    rows = []
    for directory, schedule, seed in runs:
        for perturbation, samples in perturbations:
            for sample in [*samples, MEDIAN]:
                died, kept, moved, collided, coverage, fitness = next(counts)
                factor = float(sample[1:]) if perturbation.startswith("body") and sample != MEDIAN else math.nan
                cells = died + kept + moved + collided
                rows.append(
                    RobustnessRow(
                        directory, schedule, seed, perturbation, sample, factor, len(samples), cells,
                        kept + moved, kept, moved, collided, died, coverage, fitness,
                    )
                )  # fmt: skip
    return rows


counts_strategy = st.tuples(
    st.integers(0, 50),
    st.integers(0, 50),
    st.integers(0, 50),
    st.integers(0, 50),
    st.floats(0, 100),
    st.one_of(st.floats(allow_nan=False), st.just(-math.inf)),
)
RUNS = [("runs/walker2d-smol-seed0", 'SMOL, with | and "quotes"', 3), ("runs/walker2d-vanilla-seed3", "Vanilla", 3)]


@given(
    st.integers(1, 2),
    st.sampled_from([[("body gear x0.99-1.01", ["x0.99", "x1.0056", "x1.01"])], [("starts", ["start 0"])]]),
    st.lists(counts_strategy, min_size=16, max_size=16),
)
def test_robustness_csv_reads_back_what_was_written(tmp_path_factory, runs, perturbations, counts):
    rows = grid_rows(RUNS[:runs], perturbations, counts)
    directory = tmp_path_factory.mktemp("csv")
    (directory / "robustness.csv").write_text(robustness_csv(rows))
    back = read_robustness(directory / "robustness.csv")
    for written, read in zip(rows, back, strict=True):
        assert read.directory == str((directory / written.directory).resolve())
        for name in ("schedule", "seed", "sample", "samples", "cells", "kept", "coverage", "max_fitness"):
            assert getattr(read, name) == getattr(written, name)
        assert (math.isnan(read.factor) and math.isnan(written.factor)) or read.factor == written.factor


def test_a_damaged_csv_names_its_file_and_line(tmp_path):
    rows = grid_rows(RUNS[:1], [("starts", ["start 0"])], [(0, 2, 1, 1, 9.4, 1.0)] * 2)
    text = robustness_csv(rows).splitlines()
    (tmp_path / "robustness.csv").write_text("\n".join([text[0], text[1], text[2].replace(",4,3,2,", ",4,9,2,")]))
    with pytest.raises(RunDirectoryError, match=r"robustness.csv:3: counts that do not add up"):
        read_robustness(tmp_path / "robustness.csv")
    (tmp_path / "robustness.csv").write_text("a,b\n")
    with pytest.raises(RunDirectoryError, match=r"not robustness\.csv's columns"):
        read_robustness(tmp_path / "robustness.csv")


def test_the_corrected_archive_is_qdax_s_reevaluation_function_on_the_same_samples():
    """QDax's corrected repertoire, its scoring function a fake that hands out our samples
    (one per key it splits), holds what `median_of_samples` and `reinserted` hold."""
    import jax
    import jax.numpy as jnp
    from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire
    from qdax.utils.uncertainty_metrics import reevaluation_function

    generator = np.random.default_rng(0)
    cells, samples = 24, 5
    centroids = generator.uniform(0, 1, (cells, 2)).astype(np.float32)
    filled = generator.uniform(size=cells) < 0.7
    fitness_samples = generator.normal(size=(samples, cells)).astype(np.float32)
    descriptor_samples = np.clip(centroids + generator.normal(0, 0.2, (samples, cells, 2)), 0, 1).astype(np.float32)

    key = jax.random.key(7)
    split = jax.random.split(jax.random.split(jax.random.split(key)[1])[1], samples)  # as reevaluation_function
    handed = jax.random.key_data(split)

    def scoring(genotypes, sample_key):
        index = jnp.argmax(jnp.all(handed == jax.random.key_data(sample_key), axis=-1))
        return jnp.asarray(fitness_samples)[index][genotypes], jnp.asarray(descriptor_samples)[index][genotypes], {}

    repertoire = MapElitesRepertoire.init_default(genotype=jnp.zeros((), jnp.int32), centroids=jnp.asarray(centroids))
    repertoire = repertoire.add(
        jnp.arange(cells, dtype=jnp.int32), jnp.asarray(centroids), jnp.where(filled, 0.0, -jnp.inf)
    )
    assert bool(jnp.all((repertoire.fitnesses.ravel() > -jnp.inf) == filled))
    empty = MapElitesRepertoire.init_default(genotype=jnp.zeros((), jnp.int32), centroids=jnp.asarray(centroids))
    qdax = reevaluation_function(repertoire, key, empty, scoring, samples)

    fitness, descriptor = median_of_samples(fitness_samples, descriptor_samples)
    holder, best = reinserted(centroids, np.where(filled, fitness, -np.inf), np.where(filled[:, None], descriptor, 0))
    assert best.tolist() == np.asarray(qdax.fitnesses).ravel().tolist()
    held = best > -np.inf
    assert holder[held].tolist() == np.asarray(qdax.genotypes)[held].tolist()


@given(st.sampled_from([1, 3, 5, 7]), st.integers(1, 6), st.integers(0, 2**31))
def test_an_odd_family_s_median_is_one_sample_s_result(samples, cells, seed):
    """With every sample finite, each elite's median fitness is one sample's fitness and each
    coordinate of its median descriptor one sample's: a result, not a midpoint."""
    generator = np.random.default_rng(seed)
    fitnesses = generator.normal(size=(samples, cells)).astype(np.float32)
    descriptors = generator.uniform(size=(samples, cells, 2)).astype(np.float32)
    fitness, descriptor = median_of_samples(fitnesses, descriptors)
    for cell in range(cells):
        assert fitness[cell] in fitnesses[:, cell]
        assert all(descriptor[cell, d] in descriptors[:, cell, d] for d in range(2))


def test_a_non_finite_sample_leaves_the_median_not_the_archive():
    """One NaN sample of three: the elite's median is over the other two; two of three (most):
    the elite is dead in the corrected archive."""
    fitnesses = np.asarray([[1.0, 1.0, np.nan], [3.0, np.nan, np.nan], [2.0, 5.0, 4.0]], dtype=np.float32)
    descriptors = np.zeros((3, 3, 2), dtype=np.float32)
    descriptors[:, :, 0] = [[0.1, 0.2, 0.3], [0.5, np.inf, 0.6], [0.3, 0.4, 0.9]]
    fitness, descriptor = median_of_samples(fitnesses, descriptors)
    assert fitness[0] == 2.0 and descriptor[0, 0] == pytest.approx(0.3)  # all finite: the middle one
    assert fitness[1] == 3.0 and descriptor[1, 0] == pytest.approx(0.3)  # its NaN and inf sample left out
    assert np.isnan(fitness[2])  # two of three not finite: dead


def test_reinsertion_is_qdax_s_collisions_keep_the_best():
    centroids = np.asarray([[0.0, 0.0], [1.0, 1.0], [0.0, 1.0]], dtype=np.float32)
    # cell 0's elite moves to cell 1 and beats cell 1's; cell 2 is empty
    fitnesses = np.asarray([5.0, 3.0, -np.inf], dtype=np.float32)
    descriptors = np.asarray([[0.9, 0.9], [1.0, 1.0], [0.0, 0.0]], dtype=np.float32)
    holder, best = reinserted(centroids, fitnesses, descriptors)
    assert best.tolist() == [-np.inf, 5.0, -np.inf] and holder[1] == 0


def test_the_tests_are_paired_by_seed_and_holm_adjusted_per_perturbation():
    def rows(schedule, seed, coverage, kept):
        common = (f"{schedule}{seed}", schedule, seed, "body gear x1.1")
        return [
            RobustnessRow(*common, "x1.1", 1.1, 1, 10, kept, kept, 0, 10 - kept, 0, 3.0 * kept, 1.0),
            RobustnessRow(*common, MEDIAN, math.nan, 1, 10, 5, 5, 0, 5, 0, coverage, 1.0),
        ]

    # SMOL: more robust coverage, Vanilla: a larger share kept
    measured = [r for s in range(5) for r in rows("SMOL", s, 50.0 + s, 2)]
    measured += [r for s in range(5) for r in rows("Vanilla MAP-Elites", s, 10.0 + s, 8)]
    robustness = robustness_of(measured, "walker2d", ["SMOL", "Vanilla MAP-Elites"])
    tables = robustness_tables(robustness)
    coverage, kept = tables["body gear x1.1", "robust coverage"], tables["body gear x1.1", "kept %"]
    assert coverage.medians == {"SMOL": 52.0, "Vanilla MAP-Elites": 12.0}
    assert coverage.test("Vanilla MAP-Elites", "SMOL") == "Wilcoxon"
    assert coverage.pvalues["Vanilla MAP-Elites"]["SMOL"] == pytest.approx(1 / 32)  # SMOL above at every seed
    assert coverage.adjusted["Vanilla MAP-Elites"]["SMOL"] == pytest.approx(3 / 32)  # one of three tests, Holm
    assert kept.medians == {"SMOL": 20.0, "Vanilla MAP-Elites": 80.0}
    assert kept.pvalues["Vanilla MAP-Elites"]["SMOL"] > 0.95
    share = tables["body gear x1.1", "robust share"]  # the median row's filled share: 5 of 10 cells, every run
    assert share.medians == {"SMOL": 50.0, "Vanilla MAP-Elites": 50.0}
    assert share.pvalues["Vanilla MAP-Elites"]["SMOL"] == 1.0
    markdown = robustness_markdown(robustness)
    assert "| robust share % |" not in markdown and "body gear x1.1: robust share %" in markdown
    assert "3.125e-02 (Holm 9.375e-02)" in markdown  # not bold: the adjusted p is above 0.05
    assert "over one family: the 3 tests" in markdown
    unpaired = robustness_tables(robustness_of(measured[:-2], "walker2d", ["SMOL", "Vanilla MAP-Elites"]))
    assert unpaired["body gear x1.1", "robust coverage"].test("Vanilla MAP-Elites", "SMOL") == "U"


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
