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
samples), whose `coverage` and `max_fitness` are the robust coverage and max fitness.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

from smol_dsl.rundir.files import read_text, write_text
from smol_dsl.rundir.layout import ROBUSTNESS_FILE, RunDirectoryError

MEDIAN = "median"
"""The `sample` of a perturbation's corrected archive (median over its samples)."""


@dataclass(frozen=True)
class RobustnessRow:
    """One re-scoring of one run's final archive (see the module's docstring)."""

    directory: str  # the run directory, relative to robustness.csv's where it is below it
    schedule: str  # the schedule's name, as the report groups runs
    seed: int
    perturbation: str  # "body CHANNEL", "float path" or "starts"
    sample: str  # "x0.99", "batch 256", "start 3", or MEDIAN
    factor: float  # the body factor of a "body" sample; NaN otherwise
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
    file's): a RunDirectoryError names the file and line that cannot be read, and what to do."""
    path = Path(path)
    again = f"measure again with `smol-dsl robustness {path.parent} --force`"
    reader = csv.reader(io.StringIO(read_text(path), newline=""))
    header = next(reader, None)
    if header is None or tuple(header[: len(COLUMNS)]) != COLUMNS:
        raise RunDirectoryError(f"{path}: not robustness.csv's columns ({', '.join(COLUMNS)}); {again}")
    rows = []
    for line, values in enumerate(reader, start=2):
        if len(values) != len(header):
            raise RunDirectoryError(f"{path}:{line}: {len(values)} values for {len(header)} columns; {again}")
        try:
            parsed = {name: _parse(_TYPES[name], text) for name, text in zip(COLUMNS, values, strict=False)}
            row = RobustnessRow(**parsed)
            row = replace(row, directory=str((path.parent / row.directory).resolve()))
        except ValueError as error:
            raise RunDirectoryError(f"{path}:{line}: {error}; {again}") from None
        if not 0 <= row.kept <= row.filled <= row.cells or row.filled + row.collided + row.died != row.cells:
            raise RunDirectoryError(
                f"{path}:{line}: counts that do not add up (kept <= filled <= cells, filled + collided + died = "
                f"cells); {again}"
            )
        rows.append(row)
    if not rows:
        raise RunDirectoryError(f"{path}: holds no rows; {again}")
    return rows


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
