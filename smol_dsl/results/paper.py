"""The paper's table beside ours: every cell's p-value, both, and a plain verdict.

The paper's medians and p-values ship with the package (paper_table.json, transcribed from
the paper's tables/pvalues.tex, its rows and columns named by the conditions' schedules,
`smol_dsl.results.conditions`; `paper_source()` names it): for Ant Omni, HalfCheetah and
Walker2d, the median final score of each of the eight conditions over 10 seeds, and the
one-sided Mann-Whitney U p-value that the column's final scores (SMOL, SMOL-Reverse,
SMOL-Human) are greater than the row's.

A cell's direction is which of the two schedules tends to the higher score: in the paper's
table the column's where its p-value is below 0.5, the row's above; in ours, counted over
every pair of runs (column's score above the row's, or below; ties count for neither, so
that two schedules with equal scores point nowhere, whatever their p-values). A cell *agrees* where both tables point
the same way and both p-values are significant (below 0.05), goes the *same direction*
where they point the same way but one or both are not significant, and *disagrees* where
they point opposite ways. Medians are compared only where every run used the paper's
settings: a smaller budget trains to other absolute scores, so there only directions and
significance are comparable.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from importlib import resources
from typing import TYPE_CHECKING, Any

from smol_dsl.errors import counted
from smol_dsl.results.conditions import BY_SCHEDULE, PAPER_SEEDS
from smol_dsl.results.runs import simulated_physics
from smol_dsl.results.statistics import SIGNIFICANCE, latex_escape
from smol_dsl.rundir.presets import preset_config

if TYPE_CHECKING:
    from smol_dsl.results.statistics import PValueTable
    from smol_dsl.rundir import RunRecord

VERDICTS = ("agrees", "same direction", "disagrees")


@cache
def _data() -> dict[str, Any]:
    return json.loads(resources.files("smol_dsl.results").joinpath("paper_table.json").read_text())


def paper_source() -> str:
    """Where the paper's numbers come from."""
    return _data()["source"]


@dataclass(frozen=True)
class PaperTable:
    """One task's table in the paper: its metric, each condition's median and p-values."""

    task: str
    metric: str
    medians: dict[str, float]
    pvalues: dict[str, dict[str, float | None]]  # [row][column]: P(column better than row)


def paper_table(task: str) -> PaperTable | None:
    """The paper's table for `task`, or None for a task the paper did not run."""
    entry = _data()["tasks"].get(task)
    if entry is None:
        return None
    rows = {BY_SCHEDULE[schedule].name: row for schedule, row in entry["rows"].items()}
    return PaperTable(
        task,
        entry["metric"],
        {name: row["median"] for name, row in rows.items()},
        {name: {BY_SCHEDULE[column].name: p for column, p in row["pvalues"].items()} for name, row in rows.items()},
    )


def direction(pvalue: float) -> int:
    """+1 where the column tends to the higher score, -1 where the row does, 0 for neither."""
    return (pvalue < 0.5) - (pvalue > 0.5)


def pairwise_direction(column: Sequence[float], row: Sequence[float]) -> int:
    """+1 where the column's scores beat the row's in more pairs of runs than they lose, -1
    where they lose more, 0 for neither."""
    wins = sum((a > b) - (a < b) for a in column for b in row)
    return (wins > 0) - (wins < 0)


def verdict(paper: float, ours: float, ours_direction: int | None = None) -> str:
    """A cell's verdict: agrees, same direction, or disagrees (see the module docstring);
    `ours_direction` (default: from `ours` as from the paper's) from our runs' scores."""
    mine = direction(ours) if ours_direction is None else ours_direction
    if direction(paper) != mine:
        return "disagrees"
    if paper < SIGNIFICANCE and ours < SIGNIFICANCE:
        return "agrees"
    return "same direction"


@dataclass(frozen=True)
class Cell:
    row: str
    column: str
    paper: float
    ours: float | None  # None where we have too few runs for a p-value
    ours_direction: int = 0  # `pairwise_direction` of our runs' scores

    @property
    def verdict(self) -> str:
        return "not comparable" if self.ours is None else verdict(self.paper, self.ours, self.ours_direction)


@dataclass(frozen=True)
class Comparison:
    """Our table beside the paper's for one task: every cell both have, and the medians."""

    paper: PaperTable
    ours: PValueTable
    cells: list[Cell]
    paper_settings: bool  # every run used the paper's settings: medians are comparable
    deviations: list[str]  # how the runs differ from the paper's experiment
    missing: list[str]  # the paper's conditions the runs lack

    def counts(self) -> dict[str, int]:
        tally = {name: 0 for name in (*VERDICTS, "not comparable")}
        for cell in self.cells:
            tally[cell.verdict] += 1
        return tally

    def summary(self) -> str:
        """One paragraph: what was compared and how the verdicts fall."""
        counts = self.counts()
        compared = len(self.cells) - counts["not comparable"]
        text = (
            f"Of the {len(self.cells)} p-values of the paper's {self.paper.task} table that these runs can "
            f"reproduce, {counted(compared, 'was', 'were')} compared: {counts['agrees']} agree (same direction, "
            f"both significant at {SIGNIFICANCE}), {counts['same direction']} go the same direction (not significant "
            f"in one or both), and {counts['disagrees']} disagree (opposite directions). Both sides' p-values are "
            "raw, unadjusted for the table's many tests, as the paper gives them."
        )
        if counts["not comparable"]:
            text += f" {counts['not comparable']} could not be computed (too few runs)."
        if self.missing:
            text += f" The runs lack {', '.join(self.missing)}, so their cells are left out."
        if self.paper_settings:
            text += " The runs used the paper's settings, so the medians are compared too"
            text += f" ({'; '.join(self.deviations)})." if self.deviations else "."
        else:
            text += (
                " The runs did not use the paper's settings (" + "; ".join(self.deviations) + "): only directions "
                "and significance are comparable, not the absolute medians."
            )
        return text

    def markdown(self) -> str:
        lines = [
            f"# {self.paper.task}: our final {self.ours.metric.replace('_', ' ')} beside the paper's",
            "",
            f"Paper: {paper_source()}.",
            "",
            self.summary(),
            "",
            "| row | column | paper p | our p | verdict |",
            "| --- | --- | ---: | ---: | --- |",
        ]
        for cell in self.cells:
            ours = "-" if cell.ours is None else f"{cell.ours:.3g}"
            lines.append(f"| {cell.row} | {cell.column} | {cell.paper:.3g} | {ours} | {cell.verdict} |")
        lines += ["", "| schedule | paper median | our median | our runs |", "| --- | ---: | ---: | ---: |"]
        for name, median in self.paper.medians.items():
            ours = self.ours.medians.get(name)
            shown = "-" if ours is None else (f"{ours:.4g}" if self.paper_settings else f"({ours:.4g})")
            lines.append(f"| {name} | {median:.4g} | {shown} | {self.ours.runs.get(name, 0)} |")
        if not self.paper_settings:
            lines += ["", "Our medians are in parentheses: at other settings they are not comparable with the paper's."]
        return "\n".join(lines) + "\n"

    def latex(self) -> str:
        lines = [
            f"% {latex_escape(self.summary())}",
            "\\begin{tabular}{l|l|c|c|l}",
            "\\toprule",
            "row & column & paper $p$ & our $p$ & verdict \\\\",
            "\\midrule",
        ]
        for cell in self.cells:
            ours = "-" if cell.ours is None else f"{cell.ours:.3e}"
            lines.append(
                f"{latex_escape(cell.row)} & {latex_escape(cell.column)} & {cell.paper:.3e} & {ours} & "
                f"{cell.verdict} \\\\"
            )
        lines += ["\\bottomrule", "\\end{tabular}"]
        return "\n".join(lines) + "\n"


def settings_deviations(runs: list[RunRecord]) -> list[str]:
    """How the runs' settings differ from the paper's experiment (`--preset paper` and 10
    seeds per condition); empty for a run of the paper's settings."""
    config = runs[0].config
    paper = dataclasses.asdict(preset_config(config.task, "paper"))
    ours = dataclasses.asdict(config)
    deviations = [
        f"{name} {ours[name]} (paper: {paper[name]})"
        for name in paper
        if name not in ("seed", "preset") and ours[name] != paper[name]
    ]
    return deviations


def compare_with_paper(table: PValueTable, groups: dict[str, list[RunRecord]]) -> Comparison | None:
    """Our table beside the paper's, or None where the paper has no table for the task or
    metric, or where the runs were simulated on several physics (their conditions are
    schedules on a physics, `SMOL on mjx`, and the paper's table is of one)."""
    paper = paper_table(table.task)
    if paper is None or paper.metric != table.metric:
        return None
    if len(simulated_physics(run for group in groups.values() for run in group)) > 1:
        return None
    scores = {name: [float(run.final[table.metric]) for run in group] for name, group in groups.items()}
    cells = []
    for row, pvalues in paper.pvalues.items():
        for column, value in pvalues.items():
            if value is None or row not in table.pvalues or column not in table.pvalues[row]:
                continue
            way = pairwise_direction(scores[column], scores[row])
            cells.append(Cell(row, column, value, table.pvalues[row][column], way))
    runs = [run for group in groups.values() for run in group]
    deviations = settings_deviations(runs)
    fewest = min(len(group) for group in groups.values())
    seeds = (
        [] if fewest >= PAPER_SEEDS else [f"{counted(fewest, 'seed')} per condition at least (paper: {PAPER_SEEDS})"]
    )
    missing = [name for name in paper.medians if name not in groups]
    return Comparison(paper, table, cells, not deviations, deviations + seeds, missing)
