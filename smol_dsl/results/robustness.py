"""What `smol-dsl robustness` writes from its measurements (robustness.csv's rows): per
schedule, over seeds, how much of a final archive survives each perturbation, as a table
with one-sided U-tests on robust coverage and on the share of elites kept in their cell
(`robustness_tables`, Markdown and LaTeX), a figure of survival against the body factor
(`robustness_figure`), and the section the report adds (`robustness_markdown`,
`robustness_html`). Drawn from plain rows: nothing here imports JAX.
"""

from __future__ import annotations

import html
import io
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, MaxNLocator

from smol_dsl.results.figures import legend_label, place_legend
from smol_dsl.results.output import check_writable_directory, write_files
from smol_dsl.results.report_figures import schedule_styles
from smol_dsl.results.runs import ReportError
from smol_dsl.results.statistics import SIGNIFICANCE, PValueTable, latex_escape, markdown_escape, score_table
from smol_dsl.rundir import MEDIAN, ROBUSTNESS_FILE, RobustnessRow, read_robustness
from smol_dsl.rundir.robustness import robustness_csv

if TYPE_CHECKING:
    from smol_dsl.rescoring.perturbations import Perturbations
    from smol_dsl.rundir import RunRecord

ROBUSTNESS_FILES = ("robustness.csv", "robustness.md", "robustness.tex", "robustness.png", "robustness.pdf")
"""What `smol-dsl robustness` writes (robustness.csv is `smol_dsl.rundir`'s ROBUSTNESS_FILE)."""
BODY = "body "
SURVIVAL_PANELS = (
    ("kept_share", "elites that kept their cell\n(% of the cells filled before)"),
    ("filled_share", "cells still filled\n(% of the cells filled before)"),
)


@dataclass(frozen=True)
class Robustness:
    """robustness.csv's rows with the order of the schedules (the report's)."""

    task: str
    rows: list[RobustnessRow]
    schedules: list[str]

    @property
    def perturbations(self) -> list[str]:
        return list(dict.fromkeys(row.perturbation for row in self.rows))

    def per_run(self, perturbation: str, sample: str, value: str) -> dict[str, np.ndarray]:
        """Each schedule's `value` (a RobustnessRow field or share) of one sample, one per seed."""
        return {
            name: np.asarray(
                [
                    getattr(row, value)
                    for row in self.rows
                    if row.schedule == name and row.perturbation == perturbation and row.sample == sample
                ],
                dtype=float,
            )
            for name in self.schedules
        }

    def robust_coverage(self, directory: str | Path, perturbation: str) -> float:
        """A run's robust coverage under a perturbation (its corrected archive's coverage)."""
        resolved = str(Path(directory).resolve())
        return next(
            row.coverage
            for row in self.rows
            if Path(row.directory).resolve() == Path(resolved)
            and row.perturbation == perturbation
            and row.sample == MEDIAN
        )

    def samples(self, perturbation: str) -> list[RobustnessRow]:
        """The first run's rows of a perturbation's samples (its labels and factors), in order."""
        first = self.rows[0].directory
        return [
            row
            for row in self.rows
            if row.directory == first and row.perturbation == perturbation and row.sample != MEDIAN
        ]


def robustness_of(rows: Sequence[RobustnessRow], task: str, order: Sequence[str] = ()) -> Robustness:
    """The rows, their schedules in `order` first (the report's), then as they come."""
    names = list(
        dict.fromkeys([name for name in order if any(r.schedule == name for r in rows)] + [r.schedule for r in rows])
    )
    return Robustness(task, list(rows), names)


TESTED = (
    ("robust coverage", "robust coverage", "the column schedule's robust coverage is higher than the row's"),
    ("kept %", "share of elites kept in their cell", "a larger share of the column schedule's elites keeps its cell"),
)
"""What the U-tests compare, per perturbation: (short name, in words, the alternative)."""


def robustness_tables(robustness: Robustness) -> dict[tuple[str, str], PValueTable]:
    """Per perturbation and score of TESTED, the one-sided U-tests of "the column's is
    higher than the row's", in the layout of the report's table: on robust coverage (the
    coverage of each run's corrected archive: `MEDIAN` rows), and on the share of its
    elites that kept their cell (each run's mean over the samples; a share of the archive,
    so a smaller archive is not counted against it)."""
    tables = {}
    for perturbation in robustness.perturbations:
        for name, _, _ in TESTED:
            if name == "robust coverage":
                scores = robustness.per_run(perturbation, MEDIAN, "coverage")
            else:
                scores = {s: _mean_over_samples(robustness, perturbation, s) for s in robustness.schedules}
            tables[perturbation, name] = score_table(robustness.task, f"{name} ({perturbation})", scores)
    return tables


def _tested(name: str) -> tuple[str, str]:
    """A tested score's words and alternative (`TESTED`)."""
    return next((words, alternative) for short, words, alternative in TESTED if short == name)


def _quartiles(values: np.ndarray) -> tuple[float, float, float]:
    finite = values[np.isfinite(values)]
    if not len(finite):
        return math.nan, math.nan, math.nan
    low, median, high = np.percentile(finite, [25, 50, 75])
    return float(low), float(median), float(high)


def _median_iqr(values: np.ndarray) -> str:
    low, median, high = _quartiles(values)
    return "-" if math.isnan(median) else f"{median:.1f} [{low:.1f}, {high:.1f}]"


def summary_rows(robustness: Robustness) -> tuple[list[str], list[list[str]]]:
    """The summary's header and rows: per schedule its runs, cells filled, and per
    perturbation the median [IQR] over seeds of the share of elites kept in their cell
    (averaged over the samples), of the robust coverage and of the robust max fitness."""
    perturbations = robustness.perturbations
    header = ["schedule", "runs", "cells filled"]
    for perturbation in perturbations:
        header += [
            f"{perturbation}: kept %",
            f"{perturbation}: robust coverage %",
            f"{perturbation}: robust max fitness",
        ]
    rows = []
    for name in robustness.schedules:
        cells = robustness.per_run(perturbations[0], MEDIAN, "cells")[name]
        row = [name, str(len(cells)), _median_iqr(cells)]
        for perturbation in perturbations:
            row.append(_median_iqr(_mean_over_samples(robustness, perturbation, name)))
            row.append(_median_iqr(robustness.per_run(perturbation, MEDIAN, "coverage")[name]))
            row.append(_median_iqr(robustness.per_run(perturbation, MEDIAN, "max_fitness")[name]))
        rows.append(row)
    return header, rows


def summary_markdown(robustness: Robustness) -> str:
    """The summary (`summary_rows`) as a Markdown table."""
    header, rows = summary_rows(robustness)
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + ["---:"] * (len(header) - 1)) + "|"]
    lines += ["| " + " | ".join([markdown_escape(row[0]), *row[1:]]) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def summary_html(robustness: Robustness) -> str:
    """The summary (`summary_rows`) as an HTML table."""
    esc = html.escape
    header, rows = summary_rows(robustness)
    head = "".join(f"<th>{esc(cell)}</th>" for cell in header)
    body = "".join("<tr>" + "".join(f"<td>{esc(cell)}</td>" for cell in row) + "</tr>" for row in rows)
    return (
        '<table id="robustness-summary" border="1" cellpadding="4" style="border-collapse: collapse">'
        f"<tr>{head}</tr>{body}</table>"
    )


def _mean_over_samples(robustness: Robustness, perturbation: str, name: str, value: str = "kept_share") -> np.ndarray:
    """Each run's `value` (the share of elites kept in their cell), averaged over the
    perturbation's samples."""
    samples = [row.sample for row in robustness.samples(perturbation)]
    return np.stack([robustness.per_run(perturbation, sample, value)[name] for sample in samples]).mean(axis=0)


def body_markdown(robustness: Robustness, perturbation: str) -> str:
    """Per schedule, the median [IQR] over seeds of the elites kept in their cell at each
    of a body perturbation's factors."""
    samples = robustness.samples(perturbation)
    header = ["schedule", *(f"{markdown_escape(row.sample)}" for row in samples)]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + ["---:"] * len(samples)) + "|"]
    for name in robustness.schedules:
        cells = [_median_iqr(robustness.per_run(perturbation, row.sample, "kept_share")[name]) for row in samples]
        lines.append("| " + " | ".join([markdown_escape(name), *cells]) + " |")
    return "\n".join(lines) + "\n"


EXPLAINED = (
    "Every final archive re-scored under each perturbation's samples into a fresh archive on its centroids "
    "(`smol-dsl robustness`). *kept %*: elites that kept their own cell, in % of the cells filled before (mean "
    "over the samples); *robust coverage %*: the coverage of the corrected archive, each elite at its median "
    "fitness and descriptor over the samples (QDax's `reevaluation_function`), and *robust max fitness* its best "
    "fitness. Median [25th, 75th percentile] over seeds."
)


def robustness_markdown(robustness: Robustness, level: int = 1) -> str:
    """robustness.md (a section of the report's table.md with `level` 2): the summary, each
    body perturbation's survival per factor, and the U-test tables on robust coverage."""
    heading, sub = "#" * level, "#" * (level + 1)
    parts = [f"{heading} {robustness.task}: how much of each final archive survives a change\n", EXPLAINED + "\n"]
    parts.append(summary_markdown(robustness))
    for perturbation in robustness.perturbations:
        if perturbation.startswith(BODY):
            parts += [
                f"{sub} {perturbation}: elites kept in their cell (%), per factor\n",
                body_markdown(robustness, perturbation),
            ]
    for (perturbation, name), table in robustness_tables(robustness).items():
        words, alternative = _tested(name)
        notes = "".join(f"\n- note: {note}" for note in table.notes())
        parts.append(
            f'{sub} U-tests on the {words} ({perturbation})\n\nOne-sided Mann-Whitney U: p-value of "{alternative}"; '
            f"p < {SIGNIFICANCE} in bold.\n\n{table.markdown()}{notes}\n"
        )
    return "\n".join(parts)


def robustness_html(robustness: Robustness) -> str:
    """The report page's robustness section: the summary, the U-test tables and the figure
    (robustness.png beside the page)."""
    esc = html.escape
    parts = [f'<h2 id="robustness">Robustness</h2><p>{esc(EXPLAINED.replace("*", "").replace("`", ""))}</p>']
    parts.append(summary_html(robustness))
    for number, ((perturbation, name), table) in enumerate(robustness_tables(robustness).items()):
        words, alternative = _tested(name)
        parts.append(
            f"<h3>U-tests on the {esc(words)} ({esc(perturbation)})</h3>"
            f"<p>p-value of &ldquo;{esc(alternative)}&rdquo;</p>"
        )
        parts.append(table.html(table_id=f"robustness-pvalues-{number}"))
    caption = "What survives a change of body (against the factor), of program (the float path) and of episode start."
    parts.append(
        f'<figure id="robustness-figure"><img src="robustness.png" alt="{esc(caption)}" style="max-width: 100%">'
        f'<figcaption>{esc(caption)} (<a href="robustness.pdf">PDF</a>)</figcaption></figure>'
    )
    return "\n".join(parts)


def robustness_latex(robustness: Robustness) -> str:
    """robustness.tex: the U-test tables, one per perturbation and tested score."""
    out = []
    for (perturbation, name), table in robustness_tables(robustness).items():
        words, _ = _tested(name)
        out.append(f"% {robustness.task}: {words} ({latex_escape(perturbation)}), one-sided U-tests\n{table.latex()}")
    return "\n".join(out)


def robustness_figure(robustness: Robustness) -> Figure:
    """What survives, median (line or point) and IQR (band or bar) over seeds, one colour per
    schedule: per body perturbation, the elites that kept their cell and the cells still
    filled against the factor; for the others (the float path, other starts), the same
    shares, averaged over each run's samples, side by side."""
    bodies = [p for p in robustness.perturbations if p.startswith(BODY)]
    others = [p for p in robustness.perturbations if not p.startswith(BODY)]
    rows = len(bodies) + (1 if others else 0)
    figure = Figure(figsize=(5.2 * len(SURVIVAL_PANELS), 3.4 * rows), layout="constrained")
    axes = np.asarray(figure.subplots(rows, len(SURVIVAL_PANELS), squeeze=False))
    styles = schedule_styles(robustness.schedules)
    for row_axes, perturbation in zip(axes, bodies, strict=False):
        samples = robustness.samples(perturbation)
        factors = np.asarray([row.factor for row in samples])
        order = np.argsort(factors)
        for ax, (value, label) in zip(row_axes, SURVIVAL_PANELS, strict=True):
            for name, style in zip(robustness.schedules, styles, strict=True):
                values = np.stack([robustness.per_run(perturbation, row.sample, value)[name] for row in samples])
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    low, median, high = np.nanpercentile(values, [25, 50, 75], axis=1)
                shown = legend_label(f"{name} ({values.shape[1]})")
                ax.plot(factors[order], median[order], marker=".", lw=1.5, label=shown, **style)
                ax.fill_between(factors[order], low[order], high[order], color=style["color"], alpha=0.2, lw=0)
            ax.axvline(1.0, color="0.5", ls=":", lw=1.0)
            ax.xaxis.set_major_locator(MaxNLocator(6))
            ax.xaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
            ax.set_xlabel(f"{perturbation.removeprefix(BODY)} factor (times the final body's)")
            ax.set_ylabel(label)
    if others:
        width = 0.8 / max(1, len(robustness.schedules))
        for ax, (value, label) in zip(axes[-1], SURVIVAL_PANELS, strict=True):
            for number, (name, style) in enumerate(zip(robustness.schedules, styles, strict=True)):
                for place, perturbation in enumerate(others):
                    low, median, high = _quartiles(_mean_over_samples(robustness, perturbation, name, value))
                    x = place - 0.4 + width * (number + 0.5)
                    ax.bar(x, median, width * 0.9, color=style["color"], alpha=0.6, label=None if place else name)
                    ax.errorbar([x], [median], yerr=[[median - low], [high - median]], color="0.2", capsize=2, lw=1)
            ax.set_xticks(range(len(others)), [f"{p} (final body)" for p in others])
            ax.set_ylabel(label)
    for ax in axes.flat:
        ax.set_ylim(0, 105)
        ax.grid(alpha=0.25)
    place_legend(figure, axes[0][0], title="schedule (runs)" if bodies else "schedule", title_fontsize=8)
    figure.suptitle(f"{robustness.task}: what survives a change (median and IQR over seeds)")
    return figure


def robustness_figure_and_tables(robustness: Robustness) -> dict[str, bytes]:
    """robustness.tex (the U-test tables) and the figure as PNG and PDF, by name."""
    files = {"robustness.tex": robustness_latex(robustness).encode()}
    figure = robustness_figure(robustness)
    for suffix in ("png", "pdf"):
        image = io.BytesIO()
        figure.savefig(image, format=suffix, dpi=130)
        files[f"robustness.{suffix}"] = image.getvalue()
    return files


def robustness_files(robustness: Robustness, relative_to: Path) -> dict[str, bytes]:
    """Every file `smol-dsl robustness` writes, by name, in memory: robustness.csv (run
    directories relative to `relative_to` where below it), .md, .tex, and the figure as PNG
    and PDF."""
    return {
        ROBUSTNESS_FILE: robustness_csv(robustness.rows, relative_to).encode(),
        "robustness.md": robustness_markdown(robustness).encode(),
        **robustness_figure_and_tables(robustness),
    }


def robustness_for_report(paths: Sequence[Path], groups: Mapping[str, Sequence[RunRecord]], task: str) -> Robustness:
    """The robustness.csv files at `paths`, checked against the report's runs (`groups`:
    each schedule's runs): every run has its rows, in one file only; rows of other runs
    are left out. A ReportError says what does not match and how to measure again."""
    rows: list[RobustnessRow] = []
    source: dict[str, Path] = {}
    for path in paths:
        if not Path(path).is_file():
            raise ReportError(f"{path}: no such file; measure with `smol-dsl robustness DIR...` first")
        read = read_robustness(Path(path))
        for directory in dict.fromkeys(row.directory for row in read):
            if directory in source:
                raise ReportError(f"{directory} is measured in both {source[directory]} and {path}; keep one")
            source[directory] = Path(path)
        rows += read
    reported = [str(Path(run.directory).resolve()) for runs in groups.values() for run in runs]
    missing = [directory for directory in reported if directory not in source]
    if missing:
        more = f" (nor of {len(missing) - 1} more run(s))" if len(missing) > 1 else ""
        raise ReportError(
            f"{', '.join(str(p) for p in paths)} has no measurements of {missing[0]}{more}: measure the runs you "
            "report on again with `smol-dsl robustness DIR... --force`, or give --no-robustness"
        )
    shown = set(reported)
    return robustness_of([row for row in rows if row.directory in shown], task, list(groups))


@dataclass(frozen=True)
class RobustnessReport:
    """What `measure_and_write` measured and wrote."""

    robustness: Robustness
    files: list[Path]


def check_robustness_output(out_dir: str | Path, force: bool = False) -> list[str]:
    """Refuse (ReportError) an output directory that is a file, cannot be made or written,
    or holds earlier robustness files (unless `force`); returns those files."""
    out = check_writable_directory(out_dir, ROBUSTNESS_FILES, "smol-dsl robustness")
    earlier = [name for name in ROBUSTNESS_FILES if (out / name).is_file()]
    if earlier and not force:
        raise ReportError(
            f"{out} already holds robustness measurements ({', '.join(earlier)}); give --force to replace them "
            "(force=True in Python), or another output directory with -o"
        )
    return earlier


def measure_and_write(
    paths: Sequence[str | Path],
    out_dir: str | Path,
    perturbations: Perturbations | None = None,
    *,
    force: bool = False,
    allow_mixed_environments: bool = False,
    progress: Callable[[str], None] | None = None,
) -> RobustnessReport:
    """Re-score the final archives of the finished runs below `paths` under `perturbations`
    (`smol_dsl.rescoring.robustness`) and write robustness.csv, .md, .tex, .png and .pdf into
    `out_dir`, together and atomically. Everything is checked before anything is measured
    (the output directory, the runs as `report` checks them, the perturbations), and
    measured before anything is written."""
    from smol_dsl.rescoring.perturbations import DEFAULT_PERTURBATIONS, check_perturbations
    from smol_dsl.rescoring.robustness import measure_robustness
    from smol_dsl.results.runs import load_runs

    perturbations = perturbations if perturbations is not None else DEFAULT_PERTURBATIONS
    check_robustness_output(out_dir, force)
    groups = load_runs(paths, allow_mixed_environments)
    runs = [run for group in groups.values() for run in group]
    check_perturbations(runs, perturbations)
    rows = measure_robustness(runs, perturbations, progress=progress)
    robustness = robustness_of(rows, runs[0].task, list(groups))
    files = robustness_files(robustness, Path(out_dir))
    return RobustnessReport(robustness, write_files(out_dir, files))
