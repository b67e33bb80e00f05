"""robustness.csv: what `smol-dsl robustness` measured of finished runs' final archives,
one row per (run, perturbation, sample), written beside the runs and read back by `smol-dsl
report` (`write_robustness`, `read_robustness`; the file name is `ROBUSTNESS_FILE`).

Every final archive is re-scored under each perturbation's samples (a body factor, another
episode start, another program) into a fresh archive on its centroids. A row says what
became of its elites: of the `cells` filled before, `kept` hold their own elite, `moved`
landed in another cell, `collided` lost the cell they landed in to a better elite, `died`
scored NaN or infinite; `filled` = kept + moved cells are filled after. The row whose
`sample` is `median` is the perturbation's corrected archive (QDax's
`reevaluation_function` statistics: each elite's median fitness and descriptor over the
perturbation's `samples`, an odd number, NaN samples left out), whose `coverage` and
`max_fitness` are the robust coverage and max fitness, and whose `filled_share` is the
robust share: the robust coverage relative to the cells the archive held.

The file is read back whole or not at all (`read_robustness`): every run has a row for
every sample of every perturbation of the first run's, in its order, and one `median` row
after each perturbation's samples, or the file is refused with what is missing and where.
A file of an older smol-dsl, without the `samples` column (its medians were taken over any
number of samples, a NaN sample deleting the elite), is refused with a word to measure again.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

from smol_dsl.errors import counted
from smol_dsl.rundir.files import read_text, write_text
from smol_dsl.rundir.layout import ROBUSTNESS_FILE, RunDirectoryError

MEDIAN = "median"
"""The `sample` of a perturbation's corrected archive (median over its samples)."""


@dataclass(frozen=True)
class RobustnessRow:
    """One re-scoring of one run's final archive (see the module's docstring)."""

    directory: str  # the run directory, relative to robustness.csv's where it is below it
    schedule: str  # the condition, as the report groups runs: the schedule's name (`SMOL on mjx` across physics)
    seed: int
    perturbation: str  # "body CHANNEL xLOW-HIGH", "float path", "physics NAME" or "starts"
    sample: str  # "x0.99", "batch 256", "start 3", or MEDIAN
    factor: float  # the body factor of a "body" sample; NaN otherwise
    samples: int  # the perturbation's samples (odd): the median row's median is over them
    cells: int  # cells filled before
    filled: int
    kept: int
    moved: int
    collided: int
    died: int
    coverage: float  # % of the archive's cells filled after
    max_fitness: float  # -inf where none is filled

    @property
    def filled_share(self) -> float:
        """The cells filled after, in % of those filled before."""
        return 100.0 * self.filled / self.cells if self.cells else math.nan

    @property
    def kept_share(self) -> float:
        """The elites that kept their own cell, in % of the cells filled before."""
        return 100.0 * self.kept / self.cells if self.cells else math.nan


COLUMNS = tuple(field.name for field in fields(RobustnessRow))
SHARES = ("filled_share", "kept_share")  # written after COLUMNS, derived: not read back
OLD_COLUMNS = (*(name for name in COLUMNS if name != "samples"), *SHARES)
"""robustness.csv's columns before the `samples` column (read: refused, to measure again)."""
_TYPES = {field.name: field.type for field in fields(RobustnessRow)}


def robustness_csv(rows: Sequence[RobustnessRow], relative_to: Path | None = None) -> str:
    """The rows as robustness.csv's text: COLUMNS, then the two shares (in %); each run's
    directory relative to `relative_to` (the file's directory) where the run is below it,
    so that the runs and the file move together."""
    out = io.StringIO(newline="")
    writer = csv.writer(out)
    writer.writerow([*COLUMNS, *SHARES])
    for row in rows:
        values = asdict(row)
        if relative_to is not None:
            values["directory"] = _relative(row.directory, relative_to)
        writer.writerow([_shown(values[name]) for name in COLUMNS] + [_shown(getattr(row, n)) for n in SHARES])
    return out.getvalue()


def write_robustness(directory: Path, rows: Sequence[RobustnessRow]) -> Path:
    """Write robustness.csv into `directory` (atomically; `robustness_csv`); its path."""
    path = Path(directory) / ROBUSTNESS_FILE
    write_text(path, robustness_csv(rows, path.parent))
    return path


def _relative(directory: str, base: Path) -> str:
    try:
        return Path(directory).resolve().relative_to(base.resolve()).as_posix()
    except ValueError:
        return directory


def read_robustness(path: Path) -> list[RobustnessRow]:
    """robustness.csv's rows, checked, each run's directory resolved (relative ones from the
    file's): a RunDirectoryError names the file (and line or run) that cannot be read, and
    says to measure again. Refused: other columns (an older file's included), a row whose
    counts do not add up, and a grid with a hole (`_check_grid`)."""
    path = Path(path)
    again = f"measure again with `smol-dsl robustness {path.parent} --force`"
    reader = csv.reader(io.StringIO(read_text(path), newline=""))
    header = next(reader, None)
    if header is not None and tuple(header) == OLD_COLUMNS:
        raise RunDirectoryError(
            f"{path}: written by an older smol-dsl (no `samples` column), whose corrected archives took the median "
            f"over any number of samples and deleted an elite for one NaN sample; {again}"
        )
    if header is None or tuple(header) != (*COLUMNS, *SHARES):
        raise RunDirectoryError(f"{path}: not robustness.csv's columns ({', '.join(COLUMNS + SHARES)}); {again}")
    rows, lines = [], []
    for line, values in enumerate(reader, start=2):
        if len(values) != len(header):
            raise RunDirectoryError(f"{path}:{line}: {len(values)} values for {len(header)} columns; {again}")
        try:
            parsed = {name: _parse(_TYPES[name], text) for name, text in zip(COLUMNS, values, strict=False)}
            row = RobustnessRow(**parsed)
            row = replace(row, directory=str((path.parent / row.directory).resolve()))
        except ValueError as error:
            raise RunDirectoryError(f"{path}:{line}: {error}; {again}") from None
        if (
            not 0 <= row.kept <= row.filled <= row.cells
            or row.kept + row.moved != row.filled
            or row.filled + row.collided + row.died != row.cells
            or min(row.collided, row.died) < 0
        ):
            raise RunDirectoryError(
                f"{path}:{line}: counts that do not add up (kept <= filled <= cells, kept + moved = filled, filled + "
                f"collided + died = cells); {again}"
            )
        rows.append(row)
        lines.append(line)
    if not rows:
        raise RunDirectoryError(f"{path}: holds no rows; {again}")
    _check_grid(path, rows, lines, again)
    return rows


def _check_grid(path: Path, rows: list[RobustnessRow], lines: list[int], again: str) -> None:
    """Every run has the first run's rows (run x perturbation x sample, each once, each
    perturbation's samples then its median, `samples` of them), under one schedule and seed;
    a RunDirectoryError names the run and the row that is missing, extra or out of place."""
    by_run: dict[str, list[tuple[RobustnessRow, int]]] = {}
    for row, line in zip(rows, lines, strict=True):
        by_run.setdefault(row.directory, []).append((row, line))
    first, *others = by_run
    grid = [_cell(row) for row, _ in by_run[first]]
    _check_families(path, by_run[first], again)
    for directory in others:
        mine = by_run[directory]
        cells = [_cell(row) for row, _ in mine]
        if cells != grid:
            raise RunDirectoryError(f"{path}: {directory} {_difference(cells, grid, first)}: {EDITED}; {again}")
        name = (mine[0][0].schedule, mine[0][0].seed)
        line = next((line for row, line in mine if (row.schedule, row.seed) != name), None)
        if line is not None:
            raise RunDirectoryError(f"{path}:{line}: {directory} is named with another schedule or seed; {again}")


EDITED = "the file is incomplete or was edited"


def _difference(cells: list[tuple[str, str, str, int]], grid: list[tuple[str, str, str, int]], first: str) -> str:
    """How a run's rows differ from the first run's, in words."""
    missing = next((cell for cell in grid if cell not in cells), None)
    if missing is not None:
        return f"has no row for {_described(missing)}, which {first} has"
    extra = next((cell for cell in cells if cell not in grid), None)
    if extra is not None:
        return f"has a row for {_described(extra)}, which {first} lacks"
    twice = next((cell for cell in cells if cells.count(cell) > 1), None)
    if twice is not None:
        return f"has two rows for {_described(twice)}"
    return f"has its rows in another order than {first}"


def _cell(row: RobustnessRow) -> tuple[str, str, str, int]:
    return (row.perturbation, row.sample, repr(row.factor), row.samples)


def _described(cell: tuple[str, str, str, int]) -> str:
    return f"{cell[0]}, sample {cell[1]}"


def _check_families(path: Path, rows: list[tuple[RobustnessRow, int]], again: str) -> None:
    """The first run's rows: each perturbation's samples, an odd number of them, each once and
    each saying how many there are, then its median row."""
    done: set[str] = set()
    group: list[tuple[RobustnessRow, int]] = []
    for row, line in rows:
        if row.perturbation in done:
            raise RunDirectoryError(f"{path}:{line}: {row.perturbation} after its median row; {EDITED}; {again}")
        if group and row.perturbation != group[0][0].perturbation:
            raise RunDirectoryError(f"{path}:{line}: {group[0][0].perturbation} has no median row; {EDITED}; {again}")
        group.append((row, line))
        if row.sample != MEDIAN:
            continue
        labels = [sample.sample for sample, _ in group[:-1]]
        if (
            len(labels) != row.samples
            or row.samples % 2 == 0
            or len(set(labels)) != len(labels)
            or any(sample.samples != row.samples for sample, _ in group)
        ):
            raise RunDirectoryError(
                f"{path}:{line}: the median of {row.perturbation} over {row.samples} samples, after "
                f"{counted(len(labels), 'row')} of them (an odd number, each once); {EDITED}; {again}"
            )
        done.add(row.perturbation)
        group = []
    if group:
        line, name = group[-1][1], group[0][0].perturbation
        raise RunDirectoryError(f"{path}:{line}: {name} has no median row; {EDITED}; {again}")


def _parse(kind: object, text: str) -> object:
    if kind in (int, "int"):
        return int(text)
    if kind in (float, "float"):
        return math.nan if text == "" else float(text)
    return text


def _shown(value: object) -> str:
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return str(value)
