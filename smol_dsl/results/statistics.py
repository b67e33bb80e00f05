"""The paper's statistics: for every pair of schedules, the one-sided Mann-Whitney U test
(scipy) of "the column's final scores are higher than the row's", in the layout of the
paper's `tables/pvalues.tex` (`pvalue_table` -> `PValueTable`), as Markdown, HTML or LaTeX.
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from smol_dsl.errors import counted
from smol_dsl.results.conditions import CURRICULA
from smol_dsl.results.runs import final_scores
from smol_dsl.tasks import task_spec

if TYPE_CHECKING:
    from smol_dsl.rundir import RunRecord

SIGNIFICANCE = 0.05
"""p-values below it are significant (in bold)."""


@dataclass(frozen=True)
class PValueTable:
    """Median final scores and p-values; `pvalues[row][column]` is P(column better than row)."""

    task: str
    metric: str
    rows: list[str]
    columns: list[str]
    medians: dict[str, float]
    runs: dict[str, int]
    pvalues: dict[str, dict[str, float | None]]

    def notes(self) -> list[str]:
        """Warnings about the table's power: with few runs no p-value can fall below 0.05.
        One note per pair of run counts, naming the pairs it concerns (or saying all do)."""
        by_counts: dict[tuple[int, int], list[str]] = {}
        pairs = 0
        for row in self.rows:
            for column in self.columns:
                if row == column:
                    continue
                pairs += 1
                if smallest_p(self.runs[column], self.runs[row]) >= SIGNIFICANCE:
                    counts = tuple(sorted((self.runs[column], self.runs[row])))
                    by_counts.setdefault(counts, []).append(f"{column} vs {row}")
        notes = []
        for (fewer, more), names in by_counts.items():
            runs = f"{counted(fewer, 'run')} each" if fewer == more else f"{fewer} and {counted(more, 'run')}"
            which = (
                "every pair"
                if len(names) == pairs
                else ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
            )
            notes.append(
                f"{which}: with {runs} the smallest possible p-value is {smallest_p(fewer, more):.3g}, so "
                f"{'it cannot' if len(names) == 1 else 'none can'} reach p < {SIGNIFICANCE}; run more seeds (the paper "
                "used 7 to 10)"
            )
        return notes

    @property
    def best(self) -> set[str]:
        """The schedules with the highest median (several when they tie)."""
        top = max(self.medians[name] for name in self.rows)
        return {name for name in self.rows if self.medians[name] == top}

    def _scores(self, row: str, bold: Callable[[str], str]) -> list[str]:
        """A row's median and its p-values as text, the best median and p < SIGNIFICANCE
        marked by `bold` (each format's own markup)."""
        median = _number(self.medians[row])
        cells = [bold(median) if row in self.best else median]
        for column in self.columns:
            p = self.pvalues[row][column]
            cells.append("-" if p is None else (bold(f"{p:.3e}") if p < SIGNIFICANCE else f"{p:.3e}"))
        return cells

    def markdown(self) -> str:
        header = ["schedule", "runs", "median score", *(f"p: {markdown_escape(c)} better" for c in self.columns)]
        lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + ["---:"] * (len(header) - 1)) + "|"]
        for row in self.rows:
            cells = [markdown_escape(row), str(self.runs[row]), *self._scores(row, lambda text: f"**{text}**")]
            lines.append("| " + " | ".join(cells) + " |")
        return "\n".join(lines) + "\n"

    def html(self, table_id: str = "pvalues") -> str:
        """The table as an HTML table (the best median and p < SIGNIFICANCE in bold) with
        the id `table_id`."""
        esc = html.escape
        head = "".join(f"<th>p: {esc(c)} better</th>" for c in self.columns)
        rows = []
        for row in self.rows:
            cells = [esc(row), str(self.runs[row]), *self._scores(row, lambda text: f"<b>{text}</b>")]
            rows.append("<tr>" + "".join(f"<td>{cell}</td>" for cell in cells) + "</tr>")
        return (
            f'<table id="{html.escape(table_id)}" border="1" cellpadding="4" style="border-collapse: collapse">'
            f"<tr><th>schedule</th><th>runs</th><th>median score</th>{head}</tr>" + "".join(rows) + "</table>"
        )

    def latex(self) -> str:
        columns = len(self.columns)
        lines = [
            "\\begin{tabular}{l|c|" + "c|" * columns + "}",
            "\\toprule",
            f" & Median & \\multicolumn{{{columns}}}{{c|}}{{p-values}} \\\\",
            " & score & " + " & ".join(latex_escape(c) for c in self.columns) + " \\\\",
            "\\midrule",
        ]
        for row in self.rows:
            cells = [latex_escape(row), *self._scores(row, lambda text: f"\\textbf{{{text}}}")]
            lines.append(" & ".join(cells) + " \\\\")
        lines += ["\\bottomrule", "\\end{tabular}"]
        return "\n".join(lines) + "\n"


def smallest_p(runs_a: int, runs_b: int) -> float:
    """The smallest p-value an exact one-sided U test can give with these sample sizes."""
    return 1 / math.comb(runs_a + runs_b, runs_a)


def _number(value: float) -> str:
    return f"{value:.1f}"


def markdown_escape(text: str) -> str:
    """A name as one table cell: a | would start another cell, a line break another row."""
    return "".join(char if char.isprintable() else " " for char in text).replace("|", "\\|")


LATEX_SPECIAL = {
    **{char: "\\" + char for char in "&%$#_{}"},
    "\\": "\\textbackslash{}",
    "^": "\\textasciicircum{}",
    "~": "\\textasciitilde{}",
}


def latex_escape(text: str) -> str:
    """A name as LaTeX text: its special characters escaped, control characters as spaces."""
    return "".join(LATEX_SPECIAL.get(char, char if char.isprintable() else " ") for char in text)


def pvalue_table(groups: dict[str, list[RunRecord]], metric: str | None = None) -> PValueTable:
    """The paper's table: rows every schedule, columns the SMOL curricula present (all
    schedules when none is), each cell the one-sided Mann-Whitney U p-value of "column
    better than row" on final scores."""
    task = next(iter(groups.values()))[0].task
    metric = metric or task_spec(task).default_metric
    return score_table(task, metric, final_scores(groups, metric))


def score_table(task: str, metric: str, scores: dict[str, np.ndarray]) -> PValueTable:
    """`pvalue_table`'s layout and tests on any score per run (`scores`: each schedule's,
    one per seed, in the order the table lists the schedules)."""
    from scipy.stats import mannwhitneyu

    names = list(scores)
    columns = [name for name in CURRICULA if name in scores] or names
    rows = columns + [name for name in names if name not in columns]
    pvalues: dict[str, dict[str, float | None]] = {}
    for row in rows:
        pvalues[row] = {}
        for column in columns:
            if row == column:
                pvalues[row][column] = None
            else:
                result = mannwhitneyu(scores[column], scores[row], alternative="greater")
                pvalues[row][column] = float(result.pvalue)
    return PValueTable(
        task=task,
        metric=metric,
        rows=rows,
        columns=columns,
        medians={name: float(np.median(scores[name])) for name in names},
        runs={name: len(scores[name]) for name in names},
        pvalues=pvalues,
    )
