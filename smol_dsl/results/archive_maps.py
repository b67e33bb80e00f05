"""Archive maps: a CVT-MAP-Elites archive drawn on axes coloured by its elites' fitnesses
(`draw_archive`: Voronoi cells for 2 descriptors, intervals for 1, the best per bin of the
first two for more), and one archive's figure with its coverage (`archive_figure`, a run's
archive.png). The report's side-by-side archives draw with the same `draw_archive`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import matplotlib
import matplotlib.colors
import numpy as np
from matplotlib.figure import Figure


def _fitness_image(
    ax: Any, image: np.ndarray, low: Sequence[float], high: Sequence[float], vmin: Any, vmax: Any
) -> Any:
    """An image of fitness over the first two descriptors' box (NaN: nothing there)."""
    extent = (low[0], high[0], low[1], high[1])
    return ax.imshow(image, origin="lower", extent=extent, aspect="auto", cmap="viridis", vmin=vmin, vmax=vmax)


def archive_view(dimensions: int) -> str:
    """What an archive map shows of a D-descriptor archive, for titles ("" for 2-D)."""
    if dimensions == 1:
        return "fitness along the descriptor"
    if dimensions > 2:
        return f"descriptors 1-2 of {dimensions}, best per bin"
    return ""


def draw_archive(
    ax: Any,
    centroids: np.ndarray,
    fitnesses: np.ndarray,
    low: Sequence[float],
    high: Sequence[float],
    *,
    pixels: int = 400,
    vmin: float | None = None,
    vmax: float | None = None,
) -> Any:
    """Draw an archive on ax, coloured by its elites' fitnesses; returns what a colorbar takes.

    2 descriptors: each CVT cell (its Voronoi region, rasterised by nearest centroid), empty
    ones blank with a grey dot. 1: each cell's elite's fitness over the cell's interval of the
    descriptor, empty cells as grey ticks along the bottom. More: the projection on the first
    two descriptors, binned, each bin coloured by the best elite whose centroid falls in it
    (`archive_view` says so for titles).
    """
    centroids = np.asarray(centroids, dtype=float).reshape(len(np.asarray(fitnesses).reshape(-1)), -1)
    fitnesses = np.asarray(fitnesses, dtype=float).reshape(-1)
    if centroids.shape[1] == 1:
        return _draw_archive_1d(ax, centroids[:, 0], fitnesses, low[0], high[0], vmin=vmin, vmax=vmax)
    if centroids.shape[1] > 2:
        return _draw_archive_projected(ax, centroids[:, :2], fitnesses, low, high, vmin=vmin, vmax=vmax)
    from scipy.spatial import cKDTree

    xs = np.linspace(low[0], high[0], pixels)
    ys = np.linspace(low[1], high[1], pixels)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    _, cell = cKDTree(centroids).query(grid)
    image = np.where(fitnesses[cell] > -np.inf, fitnesses[cell], np.nan).reshape(pixels, pixels)
    shown = _fitness_image(ax, image, low, high, vmin, vmax)
    filled = fitnesses > -np.inf
    ax.scatter(*centroids[~filled].T, s=2, color="0.75", label="empty cell")
    ax.set_xlabel("descriptor 1")
    ax.set_ylabel("descriptor 2")
    return shown


def _draw_archive_1d(
    ax: Any,
    centroids: np.ndarray,
    fitnesses: np.ndarray,
    low: float,
    high: float,
    *,
    vmin: float | None,
    vmax: float | None,
) -> Any:
    """A 1-D archive: a segment per filled cell (its interval, at its elite's fitness)."""
    order = np.argsort(centroids)
    centres, values = centroids[order], fitnesses[order]
    edges = np.concatenate([[low], (centres[1:] + centres[:-1]) / 2, [high]])
    filled = values > -np.inf
    finite = values[filled]
    norm = matplotlib.colors.Normalize(
        vmin=vmin if vmin is not None else (finite.min() if finite.size else None),
        vmax=vmax if vmax is not None else (finite.max() if finite.size else None),
    )
    shown = ax.scatter(centres[filled], finite, c=finite, cmap="viridis", norm=norm, s=6, zorder=3)
    colours = matplotlib.colormaps["viridis"](norm(finite)) if finite.size else "C0"
    ax.hlines(finite, edges[:-1][filled], edges[1:][filled], colors=colours, lw=2)
    ax.plot(
        centres[~filled],
        np.zeros((~filled).sum()),
        "|",
        color="0.6",
        markersize=6,
        transform=ax.get_xaxis_transform(),
        label="empty cell",
    )
    ax.set_xlim(low, high)
    if vmin is not None and vmax is not None and vmax > vmin:  # a shared scale: panels side by side compare
        ax.set_ylim(vmin - 0.05 * (vmax - vmin), vmax + 0.05 * (vmax - vmin))
    ax.set_xlabel("descriptor")
    ax.set_ylabel("fitness")
    ax.grid(alpha=0.25)
    return shown


def _draw_archive_projected(
    ax: Any,
    centroids: np.ndarray,
    fitnesses: np.ndarray,
    low: Sequence[float],
    high: Sequence[float],
    *,
    vmin: float | None,
    vmax: float | None,
) -> Any:
    """An archive of more than 2 descriptors on its first two: a grid of bins (about four
    cells each), each coloured by the best elite whose centroid projects into it."""
    bins = int(np.clip(round(np.sqrt(len(fitnesses) / 4)), 4, 50))
    span = np.asarray(high[:2], dtype=float) - np.asarray(low[:2], dtype=float)
    index = np.clip(((centroids - np.asarray(low[:2])) / span * bins).astype(int), 0, bins - 1)
    best = np.full((bins, bins), -np.inf)
    np.maximum.at(best, (index[:, 1], index[:, 0]), fitnesses)
    image = np.where(best > -np.inf, best, np.nan)
    shown = _fitness_image(ax, image, low, high, vmin, vmax)
    occupied = np.zeros((bins, bins), dtype=bool)
    occupied[index[:, 1], index[:, 0]] = True
    row, column = np.nonzero(occupied & np.isnan(image))  # bins with cells, none filled
    centre = (np.stack([column, row], axis=-1) + 0.5) / bins * span + np.asarray(low[:2])
    ax.scatter(*centre.T, s=4, color="0.75", label="empty cells only")
    ax.set_xlabel("descriptor 1")
    ax.set_ylabel("descriptor 2")
    return shown


def archive_figure(
    fitnesses: np.ndarray,
    centroids: np.ndarray,
    low: Sequence[float],
    high: Sequence[float],
    title: str,
    *,
    pixels: int = 400,
) -> Figure:
    """An archive as a map coloured by fitness (see `draw_archive` for 1 or more than 2
    descriptors), with its coverage."""
    figure = Figure(figsize=(5.6, 4.8), layout="constrained")
    ax = figure.add_subplot()
    fitnesses = np.asarray(fitnesses).reshape(-1)
    shown = draw_archive(ax, centroids, fitnesses, low, high, pixels=pixels)
    figure.colorbar(shown, ax=ax, label="fitness")
    coverage = 100 * (fitnesses > -np.inf).mean()
    view = archive_view(len(low))
    ax.set_title(f"{title}\ncoverage {coverage:.1f}%" + (f" ({view})" if view else ""), fontsize=10)
    return figure
