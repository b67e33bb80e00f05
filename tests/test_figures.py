"""smol_dsl.results' figures and `smol-dsl plot`: a run's figures drawn from its run
directory, archive maps of 1-D and more-than-2-D descriptors from plain arrays, schedule
figures of many schedules and of odd names, and `plot`'s options."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from matplotlib.figure import Figure
from synthetic_runs import many_schedules, refused, write_run

import smol_dsl
from smol_dsl.cli import main
from smol_dsl.results.archive_maps import archive_figure, archive_view, draw_archive
from smol_dsl.results.report_figures import archives_figure
from smol_dsl.results.run_figures import metrics_figure, save_run_figures
from smol_dsl.results.schedule_figures import schedule_figure
from smol_dsl.rundir import FinalArchive, RunDirectoryError, read_run


# ---------------------------------------------------------------------------- a run's figures
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


def test_run_figures_of_a_schedule_named_with_dollar_signs(tmp_path):
    """metrics.png is drawn at the end of a run: a $ in the name must not fail it then."""
    path = tmp_path / "money.sched"
    path.write_text('name "cost $\\\\frac{$ x"\n0% .. 90%: constant 1.2\n90% .. 100%: tail\n')
    out = write_run(tmp_path / "run", {"money": smol_dsl.load(path)}, "money", 0, {"max_fitness": 1.0})
    written = save_run_figures(out)
    assert [p.read_bytes()[:4] for p in written] == [b"\x89PNG"] * 2


def test_run_figures_draw_archives_of_any_dimension(tmp_path, library):
    for task in ("hopper", "ant_uni"):  # 1 and 4 descriptors
        directory = write_run(tmp_path / task, library, "human", 0, {"max_fitness": 1.0}, task=task)
        written = save_run_figures(directory)
        assert [p.name for p in written] == ["metrics.png", "archive.png"]
        assert written[1].read_bytes().startswith(b"\x89PNG")


@pytest.mark.parametrize(
    ("schedule", "columns", "label"),
    [
        ("human", ["alpha"], "α"),
        ("growth", ["alpha", "mass"], "factor"),  # mass is declared first: the panel follows metrics.csv
        ("leg-damage", ["gear[left_leg]"], "factor"),
        ("low-gravity", ["gravity"], "factor"),
    ],
)
def test_the_body_panel_draws_each_scheduled_channel(tmp_path, library, schedule, columns, label):
    run = read_run(write_run(tmp_path / "run", library, schedule, 0, {"max_fitness": 1.0}))
    body = metrics_figure(run, "t").axes[-1]
    assert [line.get_label() for line in body.get_lines()[: len(columns)]] == columns
    for line, column in zip(body.get_lines(), columns, strict=False):
        np.testing.assert_array_equal(line.get_ydata(), [row[column] for row in run.rows])
    assert body.get_ylabel() == label and (body.get_legend() is not None) == (len(columns) > 1)
    (final,) = body.get_lines()[len(columns) :]  # where the body is the final one for good
    assert final.get_xdata()[0] == run.final_body_evaluations() > 0


# ---------------------------------------------------------------------------- archive maps
def archive(cells: int, dimensions: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Centroids in [0, 1]^D and fitnesses, a third of the cells empty (-inf)."""
    rng = np.random.default_rng(seed)
    centroids = rng.uniform(size=(cells, dimensions))
    fitnesses = rng.normal(10.0, 3.0, size=cells)
    fitnesses[::3] = -np.inf
    return centroids, fitnesses


def test_a_1d_archive_is_fitness_along_the_descriptor():
    centroids, fitnesses = archive(30, 1)
    ax = Figure().add_subplot()
    shown = draw_archive(ax, centroids, fitnesses, (0.0,), (1.0,))
    filled = fitnesses > -np.inf
    points = np.asarray(shown.get_offsets())
    assert sorted(map(tuple, points)) == sorted(zip(centroids[filled, 0], fitnesses[filled], strict=True))
    (segments,) = ax.collections[1:]  # one interval per filled cell, at its fitness
    spans = np.asarray(segments.get_segments())
    assert len(spans) == filled.sum() and np.allclose(spans[:, 0, 1], spans[:, 1, 1])
    widths = spans[:, 1, 0] - spans[:, 0, 0]
    assert np.all(widths > 0) and widths.sum() < 1.0  # the filled cells' intervals, within [0, 1]
    assert ax.get_ylabel() == "fitness" and ax.get_xlim() == (0.0, 1.0)


def test_a_4d_archive_is_its_best_per_bin_on_the_first_two_descriptors():
    centroids = np.array([[0.1, 0.1, 0.0, 0.9], [0.12, 0.11, 0.9, 0.1], [0.9, 0.9, 0.5, 0.5], [0.5, 0.5, 0.5, 0.5]])
    fitnesses = np.array([1.0, 7.0, 3.0, -np.inf])  # the first two project into one bin
    ax = Figure().add_subplot()
    shown = draw_archive(ax, centroids, fitnesses, (0.0,) * 4, (1.0,) * 4)
    image = np.asarray(shown.get_array())
    assert image.shape == (4, 4)  # the fewest bins: 4 per side
    assert image[0, 0] == 7.0 and image[3, 3] == 3.0
    assert np.isnan(image[2, 2]) and np.isnan(image).sum() == 14
    empty = np.asarray(ax.collections[-1].get_offsets())
    np.testing.assert_allclose(empty, [[0.625, 0.625]])  # a bin with cells, none filled


def test_titles_say_what_the_map_shows():
    assert archive_view(2) == "" and "1-2 of 4" in archive_view(4) and "along" in archive_view(1)
    for dimensions in (1, 2, 4):
        centroids, fitnesses = archive(64, dimensions)
        figure = archive_figure(fitnesses, centroids, (0.0,) * dimensions, (1.0,) * dimensions, "t")
        assert archive_view(dimensions) in figure.axes[0].get_title()
        final = FinalArchive(fitnesses, centroids, centroids, fitnesses > -np.inf)
        panels = [("smol", seed, final) for seed in (0, 1)]
        figure = archives_figure(panels, (0.0,) * dimensions, (1.0,) * dimensions, "final")
        assert figure.get_suptitle() == ("final" if dimensions == 2 else f"final ({archive_view(dimensions)})")


# ---------------------------------------------------------------------------- schedule figures and `plot`
@pytest.mark.slow  # draws 50 schedules
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


def test_names_with_dollar_signs_are_drawn_literally(tmp_path, capsys):
    path = tmp_path / "money.sched"
    path.write_text('name "cost $\\\\frac{$ x"\n0% .. 90%: constant 1.2\n90% .. 100%: tail\n')
    assert main(["plot", str(path), "human", "-o", str(tmp_path / "money.png")]) == 0
    assert (tmp_path / "money.png").is_file()


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
