"""metrics.csv: its columns (`METRICS_SCHEMA`, one `Column` each), the row builder and the
appending writer (`MetricsLog`), all derived from the schema, so that a new float column is
one line there (and the runner giving its value); `metrics_reader` reads the file back.

A run's body is one column per scheduled channel: `alpha` for plain gear (the paper's
actuator scale; 1 for a file that does not schedule it), and one named as the channel
(`mass`, `gear[left_leg]`) for every other channel (`body_columns`).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from smol_dsl.language.channels import GEAR, Channel
from smol_dsl.rundir.files import write_text

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule

EVENTS = ("init", "train", "reevaluate", "reseed", "hold")
"""The values of metrics.csv's `event` column."""


def _finite(value: float) -> bool:
    return math.isfinite(value)


def _finite_or_minus_inf(value: float) -> bool:  # -inf: an archive that extinction emptied
    return not math.isnan(value) and value != math.inf


def _percentage(value: float) -> bool:
    return 0 <= value <= 100


def _positive(value: float) -> bool:
    return math.isfinite(value) and value > 0


@dataclass(frozen=True)
class Column:
    """One column of metrics.csv: its name, Python type (int, float or str), meaning, and the
    values it may take: a whole number of 0 or more (int), one of `choices` (str), or a float
    for which `valid` holds (finite by default), described in words by `expected`."""

    name: str
    type: type
    meaning: str
    label: str = ""  # a figure's axis label; the name with spaces when empty
    choices: tuple[str, ...] = ()
    valid: Callable[[float], bool] = _finite
    expected: str = "a finite number"
    only_on: str = ""  # the event whose rows it is measured on: empty on every other row, absent from older files

    def __post_init__(self) -> None:
        if self.type not in (int, float, str):
            raise TypeError(f"column {self.name}: the type must be int, float or str, not {self.type!r}")

    @property
    def axis_label(self) -> str:
        return self.label or self.name.replace("_", " ")

    @property
    def values(self) -> str:
        """The values the column may take, in words."""
        if self.only_on:
            return f"{self._values()} on `{self.only_on}` rows, empty on the others"
        return self._values()

    def _values(self) -> str:
        if self.type is int:
            return "a whole number of 0 or more"
        if self.type is str:
            return ", ".join(self.choices) if self.choices else "text"
        return self.expected

    def convert(self, value: Any) -> Any:
        """A value as the row writer writes it (a NumPy or JAX scalar becomes a Python one;
        None, not measured, stays None: an empty cell)."""
        if value is None and self.only_on:
            return None
        return self.type(value)

    def parse(self, text: str) -> Any:
        """The typed value of one CSV cell; a ValueError saying what is wrong ("is 'x', not ...")."""
        if self.only_on and text == "":
            return None
        shown = repr(text[:40])
        if self.type is str:
            if self.choices and text not in self.choices:
                raise ValueError(f"is {shown}, not one of {', '.join(self.choices)}")
            return text
        if self.type is int:
            try:
                whole = int(text)
            except ValueError:
                whole = -1
            if whole < 0:
                raise ValueError(f"is {shown}, not a whole number of 0 or more")
            return whole
        try:
            number = float(text)
        except ValueError:
            raise ValueError(f"is {shown}, not a number") from None
        if not self.valid(number):
            raise ValueError(f"is {shown}, but must be {self.expected}")
        return number


@dataclass(frozen=True)
class MetricsSchema:
    """The columns of metrics.csv, in order."""

    columns: tuple[Column, ...]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(column.name for column in self.columns)

    def __getitem__(self, name: str) -> Column:
        for column in self.columns:
            if column.name == name:
                return column
        raise KeyError(name)

    def row(self, **values: Any) -> dict[str, Any]:
        """A row with every column, in order, each value converted to its column's type;
        a TypeError names a missing or unknown column."""
        missing = [name for name in self.names if name not in values]
        unknown = [name for name in values if name not in self.names]
        if missing or unknown:
            raise TypeError(f"metrics row: missing column(s) {missing}, unknown column(s) {unknown}")
        return {column.name: column.convert(values[column.name]) for column in self.columns}

    def parse_row(self, texts: Mapping[str, str]) -> dict[str, Any]:
        """A CSV row's cells typed; a ValueError naming the column ("alpha is 'x', not a number").
        A column measured on some events only (`only_on`) may be absent: None, as if empty."""
        typed = {}
        for column in self.columns:
            try:
                typed[column.name] = column.parse(texts.get(column.name, ""))
            except ValueError as error:
                raise ValueError(f"{column.name} {error}") from None
            if typed[column.name] is not None and column.only_on and texts.get("event") != column.only_on:
                raise ValueError(
                    f"{column.name} is {texts[column.name]!r} on an {texts.get('event')} row: it is "
                    f"measured on {column.only_on} rows only and empty on the others"
                )
        return typed

    @property
    def required(self) -> tuple[str, ...]:
        """The columns every metrics.csv has (those measured on some events only may be
        absent from files written before they were)."""
        return tuple(column.name for column in self.columns if not column.only_on)

    def csv_text(self, rows: Sequence[Mapping[str, Any]]) -> str:
        """The header and the rows, as metrics.csv holds them."""
        text = io.StringIO(newline="")
        writer = csv.DictWriter(text, self.names)
        writer.writeheader()
        writer.writerows(rows)
        return text.getvalue()

    def markdown(self) -> str:
        """The schema as a Markdown table (docs/runner.md holds it)."""
        lines = ["| column | type | meaning | values |", "| --- | --- | --- | --- |"]
        for column in self.columns:
            lines.append(f"| `{column.name}` | {column.type.__name__} | {column.meaning} | {column.values} |")
        return "\n".join(lines) + "\n"


REEVALUATION = "reevaluate"
HOLD = "hold"
BOUNDARY_EVENTS = (REEVALUATION, HOLD)
"""The events of a phase boundary's row: it starts the next phase in the same generation."""
REEVALUATION_COLUMNS = (
    Column("reevaluated", int, "elites re-scored: the cells filled before the re-evaluation", only_on=REEVALUATION),
    Column("kept", int, "elites that kept their own cell", only_on=REEVALUATION),
    Column(
        "moved", int, "elites that went to another cell (kept + moved: the cells filled after)", only_on=REEVALUATION
    ),
    Column("collided", int, "elites that lost the cell they fell in to a better elite", only_on=REEVALUATION),
    Column("died", int, "elites removed by extinction or for a non-finite score", only_on=REEVALUATION),
)
"""What a re-evaluation did to the archive's elites: every one `reevaluated` was `kept`,
`moved`, `collided` or `died`."""
REEVALUATION_FIELDS = tuple(column.name for column in REEVALUATION_COLUMNS)


METRICS_SCHEMA = MetricsSchema(
    (
        Column("generation", int, "generations done (0: the initial population)"),
        Column("phase", int, "the phase, 0 to N − 1 (a `reevaluate` row's: the one it starts)"),
        Column("alpha", float, "the phase's α", label="α", valid=_positive, expected="a finite number above 0"),
        Column("event", str, "what the row logs (below)", choices=EVENTS),
        Column("evaluations", int, "training evaluations so far, the initial population included"),
        Column("reevaluations", int, "evaluations spent on re-evaluating the archive so far"),
        Column(
            "coverage",
            float,
            "filled cells, in % of the archive",
            label="coverage (%)",
            valid=_percentage,
            expected="a percentage from 0 to 100",
        ),
        Column(
            "max_fitness",
            float,
            "the best elite's fitness (−inf: an archive that extinction emptied)",
            valid=_finite_or_minus_inf,
            expected="a number or -inf",
        ),
        Column("qd_score", float, "QD score, with QDax's offset per filled cell", label="QD score"),
        Column("non_finite", int, "results of this row's evaluations dropped for a non-finite fitness or descriptor"),
        *REEVALUATION_COLUMNS,
    )
)
"""metrics.csv's columns. `event` is `init` (generation 0's random population), `train` (a
generation), `reevaluate` (the archive re-scored at a phase boundary), `reseed` (a
generation that re-seeded an archive extinction emptied) or `hold` (a phase boundary at which
a paced schedule's body stayed as it was: nothing re-scored, the archive kept as it is)."""
METRIC_FIELDS = METRICS_SCHEMA.names
"""metrics.csv's header."""
SCORES = ("max_fitness", "coverage", "qd_score")
"""The columns that score an archive: what a report compares and figures draw."""


ALPHA = "alpha"
"""Plain gear's column: the paper's alpha, every actuator's gear factor (1 when not scheduled)."""


def column_name(channel: Channel) -> str:
    """A channel's metrics.csv column: `alpha` for plain gear, else the channel's name."""
    return ALPHA if channel == GEAR else channel.name


def channel_column(name: str) -> Column:
    """The metrics.csv column of a scheduled channel other than plain gear (which is
    `alpha`): named as the channel (`mass`, `gear[left_leg]`), its factor in the phase."""
    return Column(name, float, f"the phase's {name} factor", valid=_positive, expected="a finite number above 0")


DEVELOPMENT = "development"
"""A paced run's column: the phase of its schedule's curve whose body it trains in."""


def development_names(clocks: int) -> tuple[str, ...]:
    """The development columns of a schedule of `clocks` `pace` lines: `development` for one,
    `development_1`, `development_2`, ... (in the file's order) for more, none for 0."""
    if clocks == 1:
        return (DEVELOPMENT,)
    return tuple(f"{DEVELOPMENT}_{k + 1}" for k in range(clocks))


def development_column(name: str) -> Column:
    """A paced run's development column (`development_names`)."""
    return Column(
        name,
        int,
        "the development step of a paced schedule's clock: the phase of its curve (on the budget's phases) "
        "whose body the row's phase trains in",
    )


def metrics_schema(channels: Sequence[Channel] = (), clocks: int = 0) -> MetricsSchema:
    """The columns of a run of these channels: METRICS_SCHEMA, whose `alpha` is plain gear's,
    one column per other channel right after `alpha`, in the order given, and after them a
    paced schedule's development columns, one per clock (`development_names`)."""
    extra = tuple(channel_column(channel.name) for channel in channels if channel != GEAR)
    extra += tuple(development_column(name) for name in development_names(clocks))
    if not extra:
        return METRICS_SCHEMA
    at = METRICS_SCHEMA.names.index(ALPHA) + 1
    return MetricsSchema(METRICS_SCHEMA.columns[:at] + extra + METRICS_SCHEMA.columns[at:])


def schedule_schema(schedule: Schedule) -> MetricsSchema:
    """The columns of a run of `schedule`: its channels' and, where it is paced, one
    development column per `pace` line."""
    return metrics_schema(schedule.channels, len(schedule.pacing.clocks) if schedule.pacing is not None else 0)


def trained_bodies(open_loop: np.ndarray, channels: Sequence[Channel], rows: Sequence[Mapping[str, Any]]) -> np.ndarray:
    """(phases, channels): the body a paced run trained in at every phase, as its `rows` log
    it; `open_loop` (its schedule's values per phase) for the phases the rows do not reach."""
    bodies = np.array(open_loop, dtype=np.float32, copy=True)
    names = [column_name(channel) for channel in channels]
    for row in rows:
        bodies[row["phase"]] = [row[name] for name in names]
    return bodies


def scheduled_columns(channels: Sequence[Channel]) -> tuple[str, ...]:
    """The columns of a run's scheduled channels, in metrics.csv's order: `alpha` first if
    plain gear is among `channels`, then the others' in the order given."""
    names = {column_name(channel) for channel in channels}
    return tuple(name for name in metrics_schema(channels).names if name in names)


def body_columns(channels: Sequence[Channel], body: Sequence[float]) -> dict[str, float]:
    """A body's columns of a metrics row: `alpha` (1 unless plain gear is among `channels`)
    and each other channel's factor, for the (C,) `body` of `channels`."""
    columns = {ALPHA: 1.0}
    columns.update({column_name(channel): float(value) for channel, value in zip(channels, body, strict=True)})
    return columns


def metrics_row(schema: MetricsSchema = METRICS_SCHEMA, **values: Any) -> dict[str, Any]:
    """A metrics.csv row of `schema`: every column, typed (`float(jax_scalar)` done here)."""
    return schema.row(**values)


class MetricsLog:
    """metrics.csv, appended row by row.

    It starts as exactly `rows` (the rows of the checkpoint the run starts from), written
    atomically: on resume, rows written after that checkpoint are dropped and a deleted
    metrics.csv comes back, so a resumed run's metrics.csv never repeats a row. With `path`
    None nothing is written. An OSError names the file.
    """

    def __init__(
        self, path: Path | None, rows: Sequence[Mapping[str, Any]], schema: MetricsSchema = METRICS_SCHEMA
    ) -> None:
        self.path = path
        self.schema = schema
        if path is not None:
            write_text(path, schema.csv_text(rows))

    def append(self, row: Mapping[str, Any]) -> None:
        if self.path is None:
            return
        try:
            with open(self.path, "a", newline="", encoding="utf-8") as file:
                csv.DictWriter(file, self.schema.names).writerow(row)
        except OSError as error:  # a full disk fails on close, with no file name
            raise OSError(error.errno, error.strerror or str(error), str(self.path)) from error
