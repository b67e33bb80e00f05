"""`smol-dsl report` and `plot` against a hostile user: every ordinary mistake (a damaged run
directory, an output that would overwrite something, odd options) is one message naming the
file, exit status 2, no traceback, and nothing written or overwritten.

The run directories are synthetic (tests/test_report.py's `write_run`, no training), built once
and copied into tmp_path before each test damages them.
"""

from __future__ import annotations

import errno
import io
import json
import shutil
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
from test_report import write_run

import smol_dsl
from smol_dsl.cli import main
from smol_dsl.results import report as report_module
from smol_dsl.results.figures import save_run_figures, schedule_figure
from smol_dsl.results.report import REPORT_FILES, ReportError, write_report

SCHEDULES = ("smol", "vanilla")
SEEDS = (0, 1, 2)
LAST_LINE = 14  # metrics.csv: the header, then generations 0..12 (SETTINGS: 208 evaluations, batch 16)


@pytest.fixture(scope="module")
def pristine(tmp_path_factory, library) -> Path:
    root = tmp_path_factory.mktemp("pristine")
    for schedule in SCHEDULES:
        for seed in SEEDS:
            score = 10.0 * seed + (5 if schedule == "smol" else 0)
            write_run(root / f"walker2d-{schedule}-seed{seed}", library, schedule, seed, {"max_fitness": score})
    return root


@pytest.fixture
def runs(pristine, tmp_path) -> Path:
    """A fresh copy of the run directories, to damage."""
    return Path(shutil.copytree(pristine, tmp_path / "runs"))


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
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir())} if directory.exists() else {}


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
        (lambda lines: [*lines, "garbage,row"], LAST_LINE + 1, "2 values where the header has 10 columns"),
        (lambda lines: [*lines[:5], "this is not,a row,,,,,,,,", *lines[5:]], 6, "is 'this is not', not a whole"),
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


# ---------------------------------------------------------------------------- seeds
def test_the_same_schedule_and_seed_twice_is_refused(pristine, tmp_path, capsys):
    again = tmp_path / "again"
    shutil.copytree(pristine / "walker2d-smol-seed1", again / "copy-of-seed1")
    err = refused(
        ["report", str(pristine), str(again), "-o", str(tmp_path / "out")],
        capsys,
        pristine / "walker2d-smol-seed1",
        again / "copy-of-seed1",
    )
    assert "seed 1 is there twice" in err


def test_seeds_that_jax_takes_as_equal_are_refused(pristine, tmp_path, capsys):
    alias = Path(shutil.copytree(pristine / "walker2d-smol-seed1", tmp_path / "alias" / "seed-4294967297"))
    config = json.loads((alias / "config.json").read_text())
    (alias / "config.json").write_text(json.dumps({**config, "seed": 1 + 2**32}))  # the same stream as seed 1
    err = refused(["report", str(pristine), str(tmp_path / "alias"), "-o", str(tmp_path / "out")], capsys, alias)
    assert "4294967297" in err
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------------------- the output
def test_an_earlier_report_is_kept_unless_forced(pristine, tmp_path, capsys, library):
    out = tmp_path / "report"
    with_ablation = Path(shutil.copytree(pristine, tmp_path / "runs"))
    for seed in SEEDS:
        write_run(with_ablation / f"random-{seed}", library, "random", seed, {"max_fitness": 1.0})
    assert main(["report", str(with_ablation), "-o", str(out)]) == 0
    capsys.readouterr()
    before = snapshot(out)
    assert "ablation-results.png" in before

    err = refused(["report", str(pristine), "-o", str(out)], capsys, out, "--force", "-o", "table.md")
    assert snapshot(out) == before  # untouched
    with pytest.raises(ReportError, match="already holds a report"):
        write_report([pristine], out)

    assert main(["report", str(pristine), "-o", str(out), "--force"]) == 0
    after = snapshot(out)
    assert after["table.md"] != before["table.md"]
    assert "ablation-results.png" not in after  # the earlier report's figure that this one does not draw
    assert not [name for name in after if name.endswith(".tmp")]
    del err


def test_output_that_is_a_file_is_refused(pristine, tmp_path, capsys):
    target = tmp_path / "results.md"
    target.write_text("my notes")
    refused(["report", str(pristine), "-o", str(target)], capsys, target, "not a directory")
    assert target.read_text() == "my notes"
    refused(["report", str(pristine), "-o", str(target / "report")], capsys, target, "is a file")
    assert target.read_text() == "my notes"


def test_output_in_a_new_directory_is_made(pristine, tmp_path, capsys):
    out = tmp_path / "not" / "yet" / "there"
    assert main(["report", str(pristine), "-o", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [
            "table.md",
            "pvalues.tex",
            "scores.csv",
            "main-results.png",
            "main-results.pdf",
            "archives.png",
            "archives.pdf",
        ]
    )
    assert "wrote" in capsys.readouterr().out


def test_a_report_file_name_taken_by_a_directory_is_refused(pristine, tmp_path, capsys):
    out = tmp_path / "out"
    (out / "scores.csv").mkdir(parents=True)
    refused(["report", str(pristine), "-o", str(out), "--force"], capsys, out / "scores.csv", "is a directory")
    assert [p.name for p in out.iterdir()] == ["scores.csv"]


def test_a_full_disk_leaves_the_earlier_report_whole(pristine, tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    assert main(["report", str(pristine), "-o", str(out)]) == 0
    capsys.readouterr()
    before = snapshot(out)
    written = []

    def full_disk(path: Path, data: bytes) -> None:
        if len(written) == 3:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        written.append(path)
        path.write_bytes(data)

    monkeypatch.setattr(report_module, "_write_bytes", full_disk)
    refused(["report", str(pristine), "-o", str(out), "--force"], capsys, "No space left on device", out)
    assert snapshot(out) == before  # nothing renamed into place, every temporary file removed
    assert len(written) == 3


def test_no_runs_missing_and_odd_directories(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    refused(["report", str(tmp_path / "empty")], capsys, tmp_path / "empty", "no run directories")
    assert not (tmp_path / "empty" / "report").exists()
    refused(["report", str(tmp_path / "missing")], capsys, tmp_path / "missing", "no such directory")
    (tmp_path / "file.txt").write_text("x")
    refused(["report", str(tmp_path / "file.txt")], capsys, tmp_path / "file.txt", "not a directory")


def test_report_option_mistakes(pristine, tmp_path, capsys):
    refused(["report", str(pristine), str(pristine), "--metric", "coverage"], capsys, "-o OUT")
    refused(["report", str(pristine), "-o", str(tmp_path / "o"), "--metric", "speed"], capsys, "unknown metric")
    refused(["report", str(pristine), str(pristine), "-o", ""], capsys, "-o: empty path")
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------------------- many schedules
def many_schedules(directory: Path, count: int) -> list[Path]:
    paths = []
    for k in range(1, count + 1):
        path = directory / f"s{k}.sched"
        path.write_text(f'name "S{k}"\n0% .. 90%: constant 1.{k:02d}\n90% .. 100%: tail\n')
        paths.append(path)
    return paths


def test_plot_of_50_schedules_fits_its_legend_without_warnings(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    paths = many_schedules(tmp_path, 50)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["plot", *map(str, paths), "-o", "many.png"]) == 0
        captured = capsys.readouterr()
        assert captured.err == ""
        assert "(50 schedules; 100 phases)" in captured.out
        assert (tmp_path / "many.png").read_bytes().startswith(b"\x89PNG")

        figure = schedule_figure([smol_dsl.load(p) for p in paths], num_phases=20)
        figure.draw_without_rendering()  # lays it out
    (legend,) = figure.legends  # below the plot, not over it
    styles = {(line.get_color(), line.get_linestyle()) for line in legend.get_lines()}
    assert len(styles) == 50  # 50 distinguishable lines
    box, page = legend.get_window_extent(), figure.bbox
    assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0 and box.y1 <= page.y1
    (axes,) = figure.axes
    assert axes.get_window_extent().y0 >= box.y1  # the axes above the legend, not shrunk to nothing
    assert axes.get_window_extent().height > 100


def test_report_of_many_schedules_without_warnings(tmp_path, capsys):
    schedules = {f"s{k}": smol_dsl.load(p) for k, p in enumerate(many_schedules(tmp_path, 12), start=1)}
    for name in schedules:
        write_run(tmp_path / "runs" / name, schedules, name, 0, {"max_fitness": float(len(name))})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["report", str(tmp_path / "runs"), "-o", str(tmp_path / "out")]) == 0
    err = capsys.readouterr().err
    assert all(line.startswith("note: ") for line in err.splitlines()), err
    assert set(REPORT_FILES) - {"ablation-results.png", "ablation-results.pdf"} == {
        p.name for p in (tmp_path / "out").iterdir()
    }


def test_names_with_table_and_latex_characters(tmp_path, capsys):
    schedules = {}
    for key, name in (("pipe", "a|b"), ("tex", "x\\y^2~_{z}")):
        path = tmp_path / f"{key}.sched"
        path.write_text(f'name "{name}"\n0% .. 90%: constant 1.2\n90% .. 100%: tail\n')
        schedules[key] = smol_dsl.load(path)
    for key in schedules:
        for seed in (0, 1):
            write_run(tmp_path / "runs" / f"{key}-{seed}", schedules, key, seed, {"max_fitness": float(seed)})
    assert main(["report", str(tmp_path / "runs"), "-o", str(tmp_path / "out")]) == 0
    markdown = (tmp_path / "out" / "table.md").read_text().splitlines()
    rows = [line for line in markdown if line.startswith("| ") and "---" not in line]
    assert all(line.count(" | ") == rows[0].count(" | ") for line in rows)  # one cell per column
    assert any(line.startswith("| a\\|b |") for line in rows)
    latex = (tmp_path / "out" / "pvalues.tex").read_text()
    assert "x\\textbackslash{}y\\textasciicircum{}2\\textasciitilde{}\\_\\{z\\}" in latex


def test_names_with_dollar_signs_are_drawn_literally(tmp_path, capsys):
    path = tmp_path / "money.sched"
    path.write_text('name "cost $\\\\frac{$ x"\n0% .. 90%: constant 1.2\n90% .. 100%: tail\n')
    assert main(["plot", str(path), "human", "-o", str(tmp_path / "money.png")]) == 0
    assert (tmp_path / "money.png").is_file()


def test_run_figures_of_a_schedule_named_with_dollar_signs(tmp_path):
    """metrics.png is drawn at the end of a run: a $ in the name must not fail it then."""
    path = tmp_path / "money.sched"
    path.write_text('name "cost $\\\\frac{$ x"\n0% .. 90%: constant 1.2\n90% .. 100%: tail\n')
    out = write_run(tmp_path / "run", {"money": smol_dsl.load(path)}, "money", 0, {"max_fitness": 1.0})
    written = save_run_figures(out)
    assert [p.read_bytes()[:4] for p in written] == [b"\x89PNG"] * 2


# ---------------------------------------------------------------------------- plot options
@pytest.mark.parametrize("seed", ["4294967296", "-1", str(2**64)])
def test_plot_seed_outside_the_seed_range(seed, capsys):
    with pytest.raises(SystemExit) as caught:
        main(["plot", "human", "--seed", seed])
    assert caught.value.code == 2
    err = capsys.readouterr().err
    assert "--seed" in err and "4294967295" in err and "Traceback" not in err


def test_plot_largest_seed(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["plot", "random", "--seed", str(2**32 - 1), "-o", "r.svg"]) == 0


def test_plot_output_that_is_a_directory(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "figures.png").mkdir()
    refused(["plot", "human", "-o", "figures.png"], capsys, "figures.png", "is a directory")
    refused(["plot", "human", "-o", "figure.gif"], capsys, "figure.gif", ".png, .svg, .pdf")
    refused(["plot", "human", "-o", "missing/figure.png"], capsys, "no such directory")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["figures.png"]
