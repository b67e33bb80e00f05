"""Archive maps of 1-D and more-than-2-D descriptors (results/figures.py), from plain arrays."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from test_report import write_run

from smol_dsl.results.figures import archive_figure, archive_view, archives_figure, draw_archive, save_run_figures
from smol_dsl.rundir import FinalArchive


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


def test_run_figures_draw_archives_of_any_dimension(tmp_path, library):
    for task in ("hopper", "ant_uni"):  # 1 and 4 descriptors
        directory = write_run(tmp_path / task, library, "human", 0, {"max_fitness": 1.0}, task=task)
        written = save_run_figures(directory)
        assert [p.name for p in written] == ["metrics.png", "archive.png"]
        assert written[1].read_bytes().startswith(b"\x89PNG")
