"""The paper's experiment in one table: its tasks, its seeds, and its eight conditions, each
with its bundled schedule, its display name, its colour in figures and its role.

Everything that names the paper's conditions reads this table: `reproduce` (which
schedules to sweep), the report (the order of rows, which schedules are the table's columns,
which are ablations), the figures (colours) and the paper comparison (paper_table.json keys
its rows by schedule). A condition's display name is its schedule's `name` directive, which
is what the report groups runs by (tests/test_paper_comparison.py holds them equal).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Role = Literal["curriculum", "baseline", "ablation"]


@dataclass(frozen=True)
class Condition:
    """One condition of the paper: `schedule` (a bundled schedule's file name, without
    `.sched`), `name` (the schedule's `name`), `color` (in every figure) and `role`: a
    `curriculum` is a column of the paper's U-test table, the `baseline` is Vanilla
    MAP-Elites, an `ablation` is drawn in its own figure."""

    schedule: str
    name: str
    color: str
    role: Role


PAPER_CONDITIONS = (
    Condition("smol", "SMOL", "#1f77b4", "curriculum"),
    Condition("smol-reverse", "SMOL-Reverse", "#ff7f0e", "curriculum"),
    Condition("human", "SMOL-Human", "#2ca02c", "curriculum"),
    Condition("vanilla", "Vanilla MAP-Elites", "#4d4d4d", "baseline"),
    Condition("random", "Random", "#9467bd", "ablation"),
    Condition("extinction-05", "Extinction 5%", "#8c564b", "ablation"),
    Condition("extinction-10", "Extinction 10%", "#e377c2", "ablation"),
    Condition("extinction-50", "Extinction 50%", "#bcbd22", "ablation"),
)
"""The paper's eight conditions, in its table's order."""
PAPER_TASKS = ("walker2d", "halfcheetah", "ant_omni")
"""The tasks the paper ran."""
PAPER_SEEDS = 10
"""Seeds per condition in the paper."""

ORDER = tuple(condition.name for condition in PAPER_CONDITIONS)
"""The conditions' names in the paper's order (a report lists other schedules after them)."""
CURRICULA = tuple(condition.name for condition in PAPER_CONDITIONS if condition.role == "curriculum")
"""The paper's table compares every schedule (rows) with these (columns)."""
ABLATIONS = tuple(condition.name for condition in PAPER_CONDITIONS if condition.role == "ablation")
"""The conditions drawn apart from the main ones."""
COLORS = {condition.name: condition.color for condition in PAPER_CONDITIONS}
"""Each condition's colour, by name; other schedules take matplotlib's next ones."""
BY_SCHEDULE = {condition.schedule: condition for condition in PAPER_CONDITIONS}
"""Each condition by its schedule's file name."""
