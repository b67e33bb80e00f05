"""The paper's statistics: for every pair of schedules, the one-sided Mann-Whitney U test
(scipy) of "the column's final scores are higher than the row's", in the layout of the
paper's `tables/pvalues.tex` (`pvalue_table` -> `PValueTable`), as Markdown, HTML or LaTeX.

Where runs of the same seed share what they are measured on (robustness: the centroids and
the episode starts), `paired_table` pairs them by seed, with the one-sided Wilcoxon
signed-rank test; and where many tables are read together, `holm` adjusts their p-values
for the multiple comparisons (`PValueTable.adjusted`, shown beside the raw ones).
"""

from __future__ import annotations

import html
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from smol_dsl.errors import counted
from smol_dsl.results.conditions import CURRICULA
from smol_dsl.results.runs import final_scores
from smol_dsl.tasks import task_spec

if TYPE_CHECKING:
    from smol_dsl.rundir import RunRecord

SIGNIFICANCE = 0.05
"""p-values below it are significant (in bold; the Holm-adjusted ones where a table has them)."""
Key = TypeVar("Key")
U_TEST = "U"
WILCOXON = "Wilcoxon"


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
    tests: dict[str, dict[str, str]] = field(default_factory=dict)  # per cell U_TEST (default) or WILCOXON
    adjusted: dict[str, dict[str, float | None]] | None = None  # Holm-adjusted p-values, where given
    family: int = 0  # how many tests the adjustment was over (this table's and any read with it)

    def test(self, row: str, column: str) -> str:
        """The test of a cell: U_TEST, or WILCOXON where `paired_table` paired the runs by seed."""
        return self.tests.get(row, {}).get(column, U_TEST)

    def smallest_possible(self, row: str, column: str) -> float:
        """The smallest p-value a cell's test can give with its runs."""
        return _smallest(self.test(row, column), self.runs[column], self.runs[row])

    def cells(self) -> list[tuple[str, str]]:
        """The (row, column) pairs that hold a p-value, row by row."""
        return [(row, column) for row in self.rows for column in self.columns if self.pvalues[row][column] is not None]

    def with_adjusted(self, adjusted: Mapping[tuple[str, str], float], family: int) -> PValueTable:
        """The table with adjusted p-values (by cell) shown beside the raw ones; bold marks them.
        `family`: how many tests they were adjusted over."""
        table = {row: {column: adjusted.get((row, column)) for column in self.columns} for row in self.rows}
        return replace(self, adjusted=table, family=family)

    def holm_adjusted(self) -> PValueTable:
        """The table with each p's Holm-adjusted value (`holm`) over all of its tests beside it."""
        return adjusted_tables({"table": self})["table"]

    def notes(self) -> list[str]:
        """Warnings about the table's power: with few runs no p-value can fall below 0.05.
        One note per test and pair of run counts, naming the pairs it concerns (or saying all do)."""
        by_counts: dict[tuple[str, int, int], list[str]] = {}
        pairs = 0
        for row, column in self.cells():
            pairs += 1
            test = self.test(row, column)
            if _smallest(test, self.runs[column], self.runs[row]) >= SIGNIFICANCE:
                fewer, more = sorted((self.runs[column], self.runs[row]))
                by_counts.setdefault((test, fewer, more), []).append(f"{column} vs {row}")
        notes = []
        for (test, fewer, more), names in by_counts.items():
            runs = f"{counted(fewer, 'run')} each" if fewer == more else f"{fewer} and {counted(more, 'run')}"
            which = (
                "every pair"
                if len(names) == pairs
                else ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
            )
            kind = "" if test == U_TEST else f" ({test}, paired by seed)"
            notes.append(
                f"{which}: with {runs}{kind} the smallest possible p-value is {_smallest(test, fewer, more):.3g}, so "
                f"{'it cannot' if len(names) == 1 else 'none can'} reach p < {SIGNIFICANCE}; run more seeds (the paper "
                "used 7 to 10)"
            )
        if self.adjusted is not None:
            notes += self._adjustment_notes()
        return notes

    def _adjustment_notes(self) -> list[str]:
        """A note where some raw p could reach significance but no adjusted one can: Holm
        multiplies the family's smallest p by the number of tests."""
        smallest = [self.smallest_possible(row, column) for row, column in self.cells()]
        reachable = [p for p in smallest if p < SIGNIFICANCE]
        if not reachable or self.family * min(reachable) < SIGNIFICANCE:
            return []
        return [
            f"Holm's adjustment over {counted(self.family, 'test')} multiplies the smallest p-value by "
            f"{self.family}: with these runs no adjusted p-value can be below {SIGNIFICANCE} (the smallest possible "
            f"is {min(1.0, self.family * min(reachable)):.3g}); run more seeds, or compare fewer schedules"
        ]

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
            if p is None:
                cells.append("-")
            elif self.adjusted is None:
                cells.append(bold(f"{p:.3e}") if p < SIGNIFICANCE else f"{p:.3e}")
            else:
                holm = self.adjusted[row][column]
                text = f"{p:.3e} (Holm {'-' if holm is None else f'{holm:.3e}'})"
                cells.append(bold(text) if holm is not None and holm < SIGNIFICANCE else text)
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


def _smallest(test: str, runs_a: int, runs_b: int) -> float:
    """The smallest p-value a one-sided test can give: an exact U test, or an exact signed-rank
    test of `runs_a` pairs (1 / 2^n)."""
    return 0.5 ** min(runs_a, runs_b) if test == WILCOXON else smallest_p(runs_a, runs_b)


def holm(pvalues: Sequence[float]) -> list[float]:
    """Holm's step-down adjustment of a family of p-values, in their order: the i-th smallest
    p becomes the largest of (m - j + 1) p_(j) over j <= i, at most 1 (m tests). Rejecting
    where the adjusted p < alpha keeps the chance of any false rejection in the family
    below alpha, whatever the tests' dependence (scipy has Benjamini-Hochberg only)."""
    count = len(pvalues)
    adjusted = [1.0] * count
    running = 0.0
    for rank, index in enumerate(sorted(range(count), key=lambda i: pvalues[i])):
        running = max(running, min(1.0, (count - rank) * pvalues[index]))
        adjusted[index] = running
    return adjusted


def adjusted_tables(tables: Mapping[Key, PValueTable]) -> dict[Key, PValueTable]:
    """The tables with Holm-adjusted p-values (`holm`), one family for all of their cells."""
    cells = [(name, cell) for name, table in tables.items() for cell in table.cells()]
    raw = [_finite_p(tables[name].pvalues[row][column]) for name, (row, column) in cells]
    adjusted = dict(zip(cells, holm(raw), strict=True))
    return {
        name: table.with_adjusted({cell: adjusted[name, cell] for cell in table.cells()}, len(cells))
        for name, table in tables.items()
    }


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


def _finite_p(p: float | None) -> float:
    """A p-value to adjust: NaN (a test of scores that are not numbers) as 1, no evidence."""
    return 1.0 if p is None or math.isnan(p) else p


def paired_table(task: str, metric: str, scores: Mapping[str, Mapping[int, float]]) -> PValueTable:
    """`score_table`'s layout on scores per run by seed (`scores`: each schedule's {seed:
    score}), paired where runs of one seed are measured on the same things: for two
    schedules with the same seeds, the one-sided Wilcoxon signed-rank test of "the column's
    is higher than the row's" on the differences seed by seed (a pair that differs nowhere:
    p = 1); for two whose seeds differ, the unpaired U test, as `score_table`'s."""
    from scipy.stats import wilcoxon

    values = {name: np.asarray([runs[seed] for seed in sorted(runs)], dtype=float) for name, runs in scores.items()}
    table = score_table(task, metric, values)  # the U tests, kept where seeds differ
    pvalues = {row: dict(cells) for row, cells in table.pvalues.items()}
    tests: dict[str, dict[str, str]] = {row: {} for row in table.rows}
    for row, column in table.cells():
        if set(scores[row]) != set(scores[column]):
            continue
        differences = np.asarray([scores[column][seed] - scores[row][seed] for seed in sorted(scores[row])])
        tests[row][column] = WILCOXON
        if not np.any(differences):
            pvalues[row][column] = 1.0
            continue
        with warnings.catch_warnings():  # zero differences: scipy says it leaves them out
            warnings.simplefilter("ignore", UserWarning)
            pvalues[row][column] = float(wilcoxon(differences, alternative="greater").pvalue)
    return replace(table, pvalues=pvalues, tests=tests)
