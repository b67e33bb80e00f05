"""metrics.csv read back: `read_metrics` types every row by the schema (`schema_of_header`:
the runner's columns plus those of the channels the header names) and checks that the rows
are the runner's, in its order; `first_tail_phase` and `final_body_evaluations` find where
the final-body tail starts in the rows read. The schema and the writer, which the runner
uses, are `metrics`'s.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from smol_dsl.language.channels import Channel
from smol_dsl.rundir.layout import CONFIG_FILE, RunDirectoryError, leave_out
from smol_dsl.rundir.metrics import (
    BOUNDARY_EVENTS,
    METRICS_SCHEMA,
    REEVALUATION_FIELDS,
    MetricsSchema,
    development_names,
    metrics_schema,
)

if TYPE_CHECKING:
    from smol_dsl.rundir.config import RunConfig


def read_metrics(
    path: Path, config: RunConfig | None = None, schema: MetricsSchema = METRICS_SCHEMA
) -> list[dict[str, Any]]:
    """Every row of a run's metrics.csv, typed by `schema` and checked: all columns there,
    numbers where numbers belong, finite where they must be, each row once and in the
    runner's order (generation 0's init row, one train or reseed row per generation, a
    reevaluate row at each phase boundary), and, given the run's `config`, within its
    generations and phases. Raises RunDirectoryError naming the file and line."""
    directory = path.parent
    rerun = f"rerun the run, {leave_out(directory)}"
    order = _RowOrder(path, config, rerun)
    rows: list[dict[str, Any]] = []
    line = 0
    try:
        with open(path, newline="", encoding="utf-8-sig") as file:  # a BOM is not part of the header
            reader = csv.reader(file)
            header, schema = _read_header(path, next(reader, None), schema, rerun)
            for values in reader:
                line = reader.line_num
                if values:  # not a blank line
                    rows.append(order.add(line, _parse_row(path, line, header, values, schema, rerun)))
    except UnicodeDecodeError:
        raise RunDirectoryError(f"{path}: not a text file (it is not UTF-8); {rerun}") from None
    except csv.Error as error:
        raise RunDirectoryError(f"{path}:{line + 1}: not readable as CSV ({error}); {rerun}") from None
    except OSError as error:
        raise RunDirectoryError(
            f"{path}: cannot be read ({error.strerror or error}); check its permissions, {leave_out(directory)}"
        ) from None
    if not rows:
        raise RunDirectoryError(f"{path}: a header but no rows; the run wrote no metrics (it stopped at once); {rerun}")
    return rows


def _read_header(
    path: Path, header: list[str] | None, schema: MetricsSchema, rerun: str
) -> tuple[list[str], MetricsSchema]:
    """metrics.csv's header, checked against the schema: every column there, none twice, and
    no channel's column the schema lacks (a column of another schedule's channel, or one
    channel's written twice in two spellings). The default schema becomes the runner's
    columns and one per scheduled channel the header names."""
    if header is None:
        raise RunDirectoryError(f"{path}: empty; the run wrote no metrics (it stopped at once); {rerun}")
    if schema is METRICS_SCHEMA:
        schema = schema_of_header(header)
    missing = [name for name in schema.required if name not in header]
    foreign = [name for name in header if name not in schema.names and _channel_of(name) is not None]
    if missing or foreign or len(set(header)) != len(header):
        if missing:
            what = f"lacks the column(s) {', '.join(missing)}"
        elif foreign:
            what = f"has a column of a channel the run does not schedule, or not as the runner writes it: {foreign[0]}"
        else:
            what = "names a column twice"
        raise RunDirectoryError(f"{path}:1: the header {what}; it should be {','.join(schema.names)}; {rerun}")
    return header, schema


def schema_of_header(header: Sequence[str]) -> MetricsSchema:
    """The schema of a metrics.csv with this header: METRICS_SCHEMA and a column for every
    header name that is a channel's (other columns are ignored)."""
    channels = []
    for name in header:
        channel = _channel_of(name) if name not in METRICS_SCHEMA.names else None
        if channel is not None and channel.name == name and channel not in channels:
            channels.append(channel)
    clocks = next((k for k in range(8, 0, -1) if set(development_names(k)) <= set(header)), 0)
    return metrics_schema(channels, clocks)


def _channel_of(name: str) -> Channel | None:
    """The channel a header name writes, in any spelling (None: no channel's)."""
    try:
        return Channel.parse(name)
    except ValueError:
        return None


def _parse_row(
    path: Path, line: int, header: list[str], values: list[str], schema: MetricsSchema, rerun: str
) -> dict[str, Any]:
    """One line's values, typed by the schema: one per column of the header, each valid."""
    if len(values) != len(header):
        raise RunDirectoryError(
            f"{path}:{line}: {len(values)} values where the header has {len(header)} columns (a row "
            f"cut short, or two rows run together); delete or repair the line, or {rerun}"
        )
    try:
        return schema.parse_row(dict(zip(header, values, strict=True)))
    except ValueError as error:
        raise RunDirectoryError(f"{path}:{line}: {error}; {rerun}") from None


class _RowOrder:
    """The rows read so far: each new one must appear once, lie within the run's config and
    follow the one before as the runner writes them."""

    def __init__(self, path: Path, config: RunConfig | None, rerun: str) -> None:
        self.path, self.config, self.rerun = path, config, rerun
        self.seen: dict[tuple[Any, ...], int] = {}  # (event, phase, evaluations) -> its line
        self.previous: dict[str, Any] | None = None
        self.previous_line = 0

    def add(self, line: int, row: dict[str, Any]) -> dict[str, Any]:
        """The row, checked against those before it."""
        where = f"{self.path}:{line}"
        key = (row["event"], row["phase"], row["evaluations"])
        if key in self.seen:
            raise RunDirectoryError(
                f"{where}: repeats line {self.seen[key]} (event {row['event']}, phase {row['phase']}, "
                f"{row['evaluations']} evaluations); every row must appear once: delete the repeated "
                f"line, or {self.rerun}"
            )
        self.seen[key] = line
        if self.config is not None:
            _check_in_run(where, row, self.config, self.rerun)
        _check_reevaluation(where, row, self.rerun)
        if self.previous is None:
            _check_first(where, row, self.rerun)
        else:
            _check_follows(where, row, self.previous, self.previous_line, self.rerun)
        self.previous, self.previous_line = row, line
        return row


def _check_in_run(where: str, row: dict[str, Any], config: RunConfig, rerun: str) -> None:
    """A row's generation and phase are among those of the run's config."""
    if row["generation"] > config.generations:
        raise RunDirectoryError(
            f"{where}: generation {row['generation']}, but {CONFIG_FILE} gives the run {config.generations} "
            f"generations; the two files are from different runs: {rerun}"
        )
    if row["phase"] >= config.num_phases:
        raise RunDirectoryError(
            f"{where}: phase {row['phase']}, but {CONFIG_FILE} gives the run {config.num_phases} phases "
            f"(0 to {config.num_phases - 1}); the two files are from different runs: {rerun}"
        )


def _check_reevaluation(where: str, row: dict[str, Any], rerun: str) -> None:
    """A reevaluate row's counts are all there or all empty (a file written before they were
    measured), and account for every elite re-scored."""
    counts = [row.get(name) for name in REEVALUATION_FIELDS]
    if all(count is None for count in counts):
        return
    reevaluated, *outcomes = counts
    if None in counts or sum(outcomes) != reevaluated:
        shown = ", ".join(
            f"{name} {'empty' if count is None else count}" for name, count in zip(REEVALUATION_FIELDS, counts)
        )
        raise RunDirectoryError(
            f"{where}: {shown}: every elite re-scored is kept, moved, collided or died, so the four add up to "
            f"reevaluated; {rerun}"
        )


def _check_first(where: str, row: dict[str, Any], rerun: str) -> None:
    """The first row is generation 0's init row."""
    if row["event"] != "init" or row["generation"] != 0:
        raise RunDirectoryError(
            f"{where}: the first row must be generation 0's init row, not generation {row['generation']}'s "
            f"{row['event']} row; the start of the file is missing: {rerun}"
        )


def _check_follows(where: str, row: dict[str, Any], previous: dict[str, Any], previous_line: int, rerun: str) -> None:
    """A row follows the one before as the runner writes them: a reevaluate or hold row in the
    same generation, any other row in the next, phases and evaluations never going back."""
    expected = previous["generation"] + (0 if row["event"] in BOUNDARY_EVENTS else 1)
    if row["event"] == "init" or row["generation"] != expected or row["phase"] < previous["phase"]:
        raise RunDirectoryError(
            f"{where}: generation {row['generation']} ({row['event']}, phase {row['phase']}) cannot follow "
            f"generation {previous['generation']} (line {previous_line}, phase {previous['phase']}); rows are "
            f"missing or out of order: {rerun}"
        )
    if row["evaluations"] < previous["evaluations"]:
        raise RunDirectoryError(
            f"{where}: {row['evaluations']} evaluations, fewer than the {previous['evaluations']} of line "
            f"{previous_line}; rows are out of order: {rerun}"
        )


def first_tail_phase(tail_start: float, num_phases: int) -> int:
    """The first phase k with k / num_phases >= tail_start (num_phases if none), robust to
    tail_start having been rounded to a float."""
    first = min(math.ceil(tail_start * num_phases), num_phases)
    while first > 0 and (first - 1) / num_phases >= tail_start:
        first -= 1
    while first < num_phases and first / num_phases < tail_start:
        first += 1
    return first


def final_body_evaluations(rows: Sequence[Mapping[str, Any]], first_tail_phase: int) -> float | None:
    """Training evaluations at the start of the first phase of the tail, where the body is
    the final one for good (None: the rows end before it)."""
    for row in rows:
        if row["phase"] >= first_tail_phase:
            return float(row["evaluations"])
    return None
