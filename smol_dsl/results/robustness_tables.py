"""The tables of `smol-dsl robustness`'s measurements: per schedule, over seeds, how much of
a final archive survives each perturbation (`summary_rows`, and per body channel the elites
kept at each factor), and the tests between schedules on the robust coverage, the robust
share and the share of elites kept (`robustness_tables`), as robustness.md and .tex and
the report's section (`robustness_markdown`, `robustness_html`, `robustness_latex`).

The tests: runs of one seed share their centroids and episode starts, so two schedules run
on the same seeds are compared seed by seed, with the one-sided Wilcoxon signed-rank test,
and two whose seeds differ with the one-sided Mann-Whitney U test (`paired_table`). Every
test of the tables is one family for Holm's adjustment (`adjusted_tables`): the adjusted
p-value stands beside the raw one, and it is the adjusted one that is bold below 0.05.
"""

from __future__ import annotations

import html
import math
from typing import TYPE_CHECKING

import numpy as np

from smol_dsl.results.statistics import (
    SIGNIFICANCE,
    WILCOXON,
    PValueTable,
    adjusted_tables,
    latex_escape,
    markdown_escape,
    paired_table,
)
from smol_dsl.rundir import MEDIAN

if TYPE_CHECKING:
    from smol_dsl.results.robustness import Robustness

TESTED = (
    ("robust coverage", "robust coverage", "the column schedule's robust coverage is higher than the row's"),
    (
        "robust share",
        "robust share (robust coverage relative to the cells filled before)",
        "the column schedule's corrected archives keep a larger share of the cells they held",
    ),
    ("kept %", "share of elites kept in their cell", "a larger share of the column schedule's elites keeps its cell"),
)
"""What the tests compare, per perturbation: (short name, in words, the alternative)."""


def scores_of(robustness: Robustness, perturbation: str, name: str) -> dict[str, dict[int, float]]:
    """Each schedule's score `name` (of TESTED) under a perturbation, by seed: the robust
    coverage and the robust share are the corrected archive's (`MEDIAN` rows: its coverage,
    and its cells in % of the cells filled before); the share kept, each run's mean over the
    samples (a share of the archive, so that a smaller archive is not counted against it)."""
    if name == "robust coverage":
        return robustness.per_seed(perturbation, MEDIAN, "coverage")
    if name == "robust share":
        return robustness.per_seed(perturbation, MEDIAN, "filled_share")
    return robustness.mean_over_samples(perturbation)


def robustness_tables(robustness: Robustness) -> dict[tuple[str, str], PValueTable]:
    """Per perturbation and score of TESTED, the one-sided tests of "the column's is higher
    than the row's" (`paired_table`: paired by seed where the seeds match), in the layout of
    the report's table, each p-value Holm-adjusted over every test of every table here."""
    tables = {
        (perturbation, name): paired_table(
            robustness.task, f"{name} ({perturbation})", scores_of(robustness, perturbation, name)
        )
        for perturbation in robustness.perturbations
        for name, _, _ in TESTED
    }
    return adjusted_tables(tables)


def _tested(name: str) -> tuple[str, str]:
    """A tested score's words and alternative (`TESTED`)."""
    return next((words, alternative) for short, words, alternative in TESTED if short == name)


def tests_explained(table: PValueTable, tests: int) -> list[str]:
    """What a table's tests are, paired or not and why, and the family Holm adjusts over."""
    unpaired = [f"{column} vs {row}" for row, column in table.cells() if table.test(row, column) != WILCOXON]
    paired = (
        "one-sided Wilcoxon signed-rank tests, paired by seed (runs of one seed share their centroids and episode "
        "starts)"
    )
    if unpaired:
        paired = (
            f"one-sided Mann-Whitney U tests for {', '.join(unpaired)} (their seeds differ, so their runs cannot "
            f"be paired); elsewhere {paired}"
        )
    notes = [
        paired,
        f"Holm-adjusted p-values beside the raw ones, over one family: the {tests} tests of every table of this "
        f"section; bold: adjusted p < {SIGNIFICANCE}",
    ]
    smallest = min((table.smallest_possible(row, column) for row, column in table.cells()), default=1.0)
    if tests * smallest >= SIGNIFICANCE:
        notes.append(
            f"with these runs the smallest possible p-value is {smallest:.3g}, so over {tests} tests no adjusted "
            f"p-value here can reach {SIGNIFICANCE} (Holm's smallest is {tests} times the smallest p); run more seeds"
        )
    return notes


def quartiles(values: np.ndarray) -> tuple[float, float, float]:
    """The 25th, 50th and 75th percentiles of the finite values (NaN where none is)."""
    finite = values[np.isfinite(values)]
    if not len(finite):
        return math.nan, math.nan, math.nan
    low, median, high = np.percentile(finite, [25, 50, 75])
    return float(low), float(median), float(high)


def _median_iqr(values: np.ndarray | dict[int, float]) -> str:
    if isinstance(values, dict):
        values = np.asarray([values[seed] for seed in sorted(values)], dtype=float)
    low, median, high = quartiles(values)
    return "-" if math.isnan(median) else f"{median:.1f} [{low:.1f}, {high:.1f}]"


def summary_rows(robustness: Robustness) -> tuple[list[str], list[list[str]]]:
    """The summary's header and rows: per schedule its runs, cells filled, and per
    perturbation the median [IQR] over seeds of the share of elites kept in their cell
    (averaged over the samples), of the robust coverage, of the robust share and of the
    robust max fitness."""
    perturbations = robustness.perturbations
    header = ["schedule", "runs", "cells filled"]
    for perturbation in perturbations:
        header += [
            f"{perturbation}: kept %",
            f"{perturbation}: robust coverage %",
            f"{perturbation}: robust share %",
            f"{perturbation}: robust max fitness",
        ]
    rows = []
    for name in robustness.schedules:
        cells = robustness.per_run(perturbations[0], MEDIAN, "cells")[name]
        row = [name, str(len(cells)), _median_iqr(cells)]
        for perturbation in perturbations:
            row.append(_median_iqr(robustness.mean_over_samples(perturbation)[name]))
            for value in ("coverage", "filled_share", "max_fitness"):
                row.append(_median_iqr(robustness.per_run(perturbation, MEDIAN, value)[name]))
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


def body_markdown(robustness: Robustness, channel: str) -> str:
    """Per schedule, the median [IQR] over seeds of the elites kept in their cell at each
    factor of a body channel's families."""
    samples = robustness.channel_samples(channel)
    header = ["schedule", *(f"{markdown_escape(row.sample)}" for row in samples)]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + ["---:"] * len(samples)) + "|"]
    for name in robustness.schedules:
        cells = [_median_iqr(robustness.per_run(row.perturbation, row.sample, "kept_share")[name]) for row in samples]
        lines.append("| " + " | ".join([markdown_escape(name), *cells]) + " |")
    return "\n".join(lines) + "\n"


EXPLAINED = (
    "Every final archive re-scored under each perturbation's samples into a fresh archive on its centroids "
    "(`smol-dsl robustness`). *kept %*: elites that kept their own cell, in % of the cells filled before (mean "
    "over the samples); *robust coverage %*: the coverage of the corrected archive, each elite at its median "
    "fitness and descriptor (coordinate by coordinate) over the perturbation's samples, an odd number of them, "
    "NaN samples left out and the elite dead where most are NaN (QDax's `reevaluation_function` with its median "
    "extractors); *robust share %*: the corrected archive's cells in % of the cells filled before; *robust max "
    "fitness*: its best fitness. Median [25th, 75th percentile] over seeds."
)


def robustness_markdown(robustness: Robustness, level: int = 1) -> str:
    """robustness.md (a section of the report's table.md with `level` 2): the summary, each
    body channel's survival per factor, and the tests' tables."""
    heading, sub = "#" * level, "#" * (level + 1)
    parts = [f"{heading} {robustness.task}: how much of each final archive survives a change\n", EXPLAINED + "\n"]
    parts.append(summary_markdown(robustness))
    for channel in robustness.channels:
        heading = f"{sub} body {channel}: elites kept in their cell (%), per factor\n"
        parts += [heading, body_markdown(robustness, channel)]
    tables = robustness_tables(robustness)
    tests = sum(len(table.cells()) for table in tables.values())
    for (perturbation, name), table in tables.items():
        words, alternative = _tested(name)
        notes = "".join(f"\n- note: {note}" for note in [*tests_explained(table, tests), *table.notes()])
        parts.append(
            f'{sub} Tests on the {words} ({perturbation})\n\np-value of "{alternative}" (Holm-adjusted in '
            f"brackets).\n\n{table.markdown()}{notes}\n"
        )
    return "\n".join(parts)


def robustness_html(robustness: Robustness) -> str:
    """The report page's robustness section: the summary, the tests' tables and the figure
    (robustness.png beside the page)."""
    esc = html.escape
    parts = [f'<h2 id="robustness">Robustness</h2><p>{esc(EXPLAINED.replace("*", "").replace("`", ""))}</p>']
    parts.append(summary_html(robustness))
    tables = robustness_tables(robustness)
    tests = sum(len(table.cells()) for table in tables.values())
    for number, ((perturbation, name), table) in enumerate(tables.items()):
        words, alternative = _tested(name)
        notes = "".join(f"<li>{esc(note)}</li>" for note in [*tests_explained(table, tests), *table.notes()])
        parts.append(
            f"<h3>Tests on the {esc(words)} ({esc(perturbation)})</h3>"
            f"<p>p-value of &ldquo;{esc(alternative)}&rdquo; (Holm-adjusted in brackets)</p>"
        )
        parts.append(table.html(table_id=f"robustness-pvalues-{number}") + f"<ul>{notes}</ul>")
    caption = (
        "What survives a change of body (against the factor), of program (the float path), of physics (where "
        "measured) and of episode start."
    )
    parts.append(
        f'<figure id="robustness-figure"><img src="robustness.png" alt="{esc(caption)}" style="max-width: 100%">'
        f'<figcaption>{esc(caption)} (<a href="robustness.pdf">PDF</a>)</figcaption></figure>'
    )
    return "\n".join(parts)


def robustness_latex(robustness: Robustness) -> str:
    """robustness.tex: the tests' tables, one per perturbation and tested score, each p-value
    with its Holm-adjusted one in brackets."""
    tables = robustness_tables(robustness)
    tests = sum(len(table.cells()) for table in tables.values())
    out = []
    for (perturbation, name), table in tables.items():
        words, _ = _tested(name)
        notes = "".join(f"% {latex_escape(note)}\n" for note in tests_explained(table, tests))
        out.append(f"% {robustness.task}: {words} ({latex_escape(perturbation)})\n{notes}{table.latex()}")
    return "\n".join(out)
