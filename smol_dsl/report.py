"""The paper's analysis of finished runs: the U-test table and the figures.

`load_runs(paths)` finds run directories (written by `smol-dsl run` or `sweep`), checks
every one of them (its config.json, certificate and schedule, every row of metrics.csv, and
its final archive.npz), checks that they can be compared (one task, the same settings,
finished, no run counted twice), and groups them by schedule. `pvalue_table` gives, for
every pair of schedules, the one-sided Mann-Whitney U test (scipy) of "the column's final
scores are higher than the row's", in the layout of the paper's `tables/pvalues.tex`;
`write_report` writes it as Markdown and LaTeX with the figures: everything is read and
drawn before the first file is written, every file is written atomically, and an earlier
report is replaced only with `force=True` (`--force`).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import json
import math
import os
import warnings
import zipfile
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smol_dsl.errors import UserInputError
from smol_dsl.runner.config import RunConfig
from smol_dsl.runner.run import METRIC_FIELDS, alpha_one_evaluations

METRICS = ("max_fitness", "coverage", "qd_score")
METRIC_LABELS = {"max_fitness": "max fitness", "coverage": "coverage (%)", "qd_score": "QD score"}
DEFAULT_METRIC = {"walker2d": "max_fitness", "halfcheetah": "max_fitness", "ant_omni": "coverage"}
"""The paper's final score per task."""

COLUMNS = ("SMOL", "SMOL-Reverse", "SMOL-Human")
"""The paper's table compares every schedule (rows) with these curricula (columns)."""
MAIN = ("Vanilla MAP-Elites", "SMOL", "SMOL-Reverse", "SMOL-Human")
ABLATIONS = ("Random", "Extinction 5%", "Extinction 10%", "Extinction 50%")
ORDER = ("SMOL", "SMOL-Reverse", "SMOL-Human", "Vanilla MAP-Elites", *ABLATIONS)
SIGNIFICANCE = 0.05

EVENTS = ("init", "train", "reevaluate", "reseed")
"""The `event` column of metrics.csv."""
WHOLE_FIELDS = ("generation", "phase", "evaluations", "reevaluations", "non_finite")
SEED_MODULUS = 2**32
"""JAX takes a seed modulo 2**32: seeds S and S + 2**32 give the same run."""
ARCHIVE_ARRAYS = ("fitnesses", "descriptors", "centroids", "filled")
FIGURE_STEMS = ("main-results", "ablation-results", "archives")
REPORT_FILES = (
    "table.md",
    "pvalues.tex",
    "scores.csv",
    *(f"{stem}{suffix}" for stem in FIGURE_STEMS for suffix in (".png", ".pdf")),
)
"""Every file a report may write: an output directory holding any of them holds a report."""
MOST_PROBLEMS = 5
"""How many unusable run directories one error lists."""


class ReportError(UserInputError):
    """Run directories that cannot be reported on together, or an output directory that
    cannot take the report, with what to do instead."""


def _leave_out(directory: Path) -> str:
    return f"or move {directory} out of the directories you report on"


@dataclass(frozen=True)
class FinalArchive:
    """A run's final archive.npz without its policies: what the report reads and draws.
    `fitnesses` (C,), -inf in empty cells; `descriptors` and `centroids` (C, D); `filled` (C,)."""

    fitnesses: np.ndarray
    descriptors: np.ndarray
    centroids: np.ndarray
    filled: np.ndarray


@dataclass(frozen=True)
class RunRecord:
    """A run directory: its settings, schedule, metrics log and (once finished) final archive."""

    directory: Path
    config: RunConfig
    schedule: str  # the schedule's name
    schedule_source: str
    tail_start: float
    rows: list[dict[str, Any]]
    archive: FinalArchive | None = None  # None until the run has finished

    @property
    def task(self) -> str:
        return self.config.task

    @property
    def seed(self) -> int:
        return self.config.seed

    @property
    def settings(self) -> dict[str, Any]:
        """The run's configuration without its seed: what runs compared must share."""
        settings = dataclasses.asdict(self.config)
        del settings["seed"]
        return settings

    @property
    def final(self) -> dict[str, Any]:
        return self.rows[-1]

    @property
    def finished(self) -> bool:
        return self.final["generation"] >= self.config.generations

    def curve(self, metric: str) -> tuple[np.ndarray, np.ndarray]:
        """Training evaluations and the metric, one point per logged row."""
        evaluations = np.asarray([row["evaluations"] for row in self.rows], dtype=float)
        return evaluations, np.asarray([row[metric] for row in self.rows], dtype=float)

    def alpha_one_evaluations(self) -> float | None:
        """Training evaluations when alpha becomes 1 for good (the first tail phase starts)."""
        phases = self.config.num_phases
        first_tail = min(math.ceil(self.tail_start * phases), phases)  # the first k with k / phases >= tail
        while first_tail > 0 and (first_tail - 1) / phases >= self.tail_start:
            first_tail -= 1  # rounding
        while first_tail < phases and first_tail / phases < self.tail_start:
            first_tail += 1
        return alpha_one_evaluations(self.rows, first_tail)


RUN_MARKERS = ("schedule.sched", "certificate.json", "archive.npz", "checkpoint.npz")
"""Besides metrics.csv, files that make a directory with a config.json a run directory."""


def is_run_directory(path: Path) -> bool:
    """Whether path looks like a run directory, whole or not: it holds metrics.csv, or a
    config.json with another file the runner writes. `read_run` says what is wrong with it."""
    if (path / "metrics.csv").is_file():
        return True
    return (path / "config.json").is_file() and any((path / name).is_file() for name in RUN_MARKERS)


def find_run_directories(paths: Iterable[str | Path]) -> list[Path]:
    """Run directories given, or found anywhere below the given directories, each once."""
    found: dict[Path, None] = {}
    for given in paths:
        path = Path(given)
        if not path.exists():
            raise ReportError(f"{path}: no such directory")
        if not path.is_dir():
            raise ReportError(f"{path} is not a directory; give run or sweep directories")
        if is_run_directory(path):
            candidates = [path]
        else:
            below = {p.parent for name in ("config.json", "metrics.csv") for p in path.rglob(name)}
            candidates = sorted(below)
        for candidate in candidates:
            if is_run_directory(candidate):
                found.setdefault(candidate.resolve(), None)
    return list(found)


def read_run(directory: Path) -> RunRecord:
    """Read and check a run directory: config.json, certificate.json, schedule.sched, every
    row of metrics.csv and, if the run has finished, archive.npz. Raises ReportError naming
    the file (and line) that cannot be used, and what to do."""
    directory = Path(directory)
    config = read_config(directory / "config.json")
    name, tail_start = _read_certificate(directory / "certificate.json")
    source = _read_text(directory / "schedule.sched")
    rows = read_metrics(directory / "metrics.csv", config)
    run = RunRecord(directory, config, name, source, tail_start, rows)
    if run.finished:
        run = dataclasses.replace(run, archive=read_final_archive(directory, config))
    return run


def _read_text(path: Path) -> str:
    directory = path.parent
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ReportError(
            f"{path}: missing; every run directory holds it (the runner writes it first), so {directory} is "
            f"incomplete: rerun that run, {_leave_out(directory)}"
        ) from None
    except UnicodeDecodeError:
        raise ReportError(
            f"{path}: not a text file (it is not UTF-8); rerun that run, {_leave_out(directory)}"
        ) from None
    except OSError as error:
        raise ReportError(
            f"{path}: cannot be read ({error.strerror or error}); check its permissions, {_leave_out(directory)}"
        ) from None


CONFIG_TYPES = {"str": str, "int": int, "float": float, "tuple[int, ...]": list}
CONFIG_AT_LEAST_ONE = ("evaluations", "batch_size", "num_phases", "num_centroids", "episode_length")


def read_config(path: Path) -> RunConfig:
    """A run's config.json, checked: every setting present, of its type, and usable."""
    from smol_dsl.tasks import TASK_NAMES

    text = _read_text(path)
    fix = f"this is not a config.json that smol-dsl wrote; rerun the run, {_leave_out(path.parent)}"
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as error:
        where = f":{error.lineno}" if isinstance(error, json.JSONDecodeError) else ""
        raise ReportError(f"{path}{where}: not valid JSON ({error}); {fix}") from None
    if not isinstance(data, dict):
        raise ReportError(f"{path}: holds {type(data).__name__}, not the run's settings; {fix}")
    fields = {field.name: field for field in dataclasses.fields(RunConfig)}
    missing = [name for name, field in fields.items() if name not in data and field.default is dataclasses.MISSING]
    if missing:
        raise ReportError(f"{path}: lacks the setting(s) {', '.join(missing)}; {fix}")
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ReportError(f"{path}: unknown setting(s) {', '.join(unknown)} (from another smol-dsl version?); {fix}")
    for name, value in data.items():
        kind = CONFIG_TYPES.get(str(fields[name].type))
        if kind is None:
            continue
        if kind is float:
            ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        elif kind is list:
            ok = isinstance(value, list) and all(
                isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in value
            )
        else:
            ok = isinstance(value, kind) and not isinstance(value, bool)
        if not ok:
            expected = {str: "a string", int: "a whole number", float: "a finite number", list: "a list of sizes"}[kind]
            raise ReportError(f"{path}: {name} is {json.dumps(value)[:40]}, not {expected}; {fix}")
    if data["task"] not in TASK_NAMES:
        raise ReportError(f"{path}: unknown task {data['task']!r} (the tasks are {', '.join(TASK_NAMES)}); {fix}")
    for name in CONFIG_AT_LEAST_ONE:
        if name in data and data[name] < 1:
            raise ReportError(f"{path}: {name} is {data[name]}, but must be at least 1; {fix}")
    data["hidden_layer_sizes"] = tuple(data["hidden_layer_sizes"])
    try:
        config = RunConfig(**data)
    except (UserInputError, ValueError) as error:  # a seed outside 0 .. 2**32 - 1, say
        raise ReportError(
            f"{path}: {error}; rerun the run with settings the runner accepts, {_leave_out(path.parent)}"
        ) from None
    if config.generations < 1:
        raise ReportError(
            f"{path}: {config.evaluations} evaluations in batches of {config.batch_size} make no generation; {fix}"
        )
    if config.generations < config.num_phases:
        raise ReportError(
            f"{path}: {config.num_phases} phases but only {config.generations} generations; the runner refuses "
            f"such settings, so smol-dsl did not write this file; {fix}"
        )
    return config


def _read_certificate(path: Path) -> tuple[str, float]:
    """The schedule's name and the start of its alpha = 1 tail, from certificate.json."""
    fix = f"rerun the run, {_leave_out(path.parent)}"
    try:
        data = json.loads(_read_text(path))
    except (json.JSONDecodeError, RecursionError) as error:
        raise ReportError(f"{path}: not valid JSON ({error}); {fix}") from None
    name = data.get("name") if isinstance(data, dict) else None
    tail = data.get("tail_start") if isinstance(data, dict) else None
    if not isinstance(name, str) or not name:
        raise ReportError(f'{path}: no schedule name ("name"); {fix}')
    if not isinstance(tail, int | float) or isinstance(tail, bool) or not 0 <= tail <= 1:
        raise ReportError(f'{path}: "tail_start" must be a number from 0 to 1, not {json.dumps(tail)[:40]}; {fix}')
    return name, float(tail)


def read_metrics(path: Path, config: RunConfig) -> list[dict[str, Any]]:
    """Every row of a run's metrics.csv, typed and checked: all columns there, numbers where
    numbers belong, finite where they must be, each row once and in the runner's order
    (generation 0's init row, one train or reseed row per generation, a reevaluate row at each
    phase boundary). Raises ReportError naming the file and line."""
    directory = path.parent
    rerun = f"rerun the run, {_leave_out(directory)}"
    rows: list[dict[str, Any]] = []
    lines: list[int] = []
    seen: dict[tuple[Any, ...], int] = {}
    line = 0
    try:
        with open(path, newline="", encoding="utf-8") as file:
            reader = csv.reader(file)
            header = next(reader, None)
            if header is None:
                raise ReportError(f"{path}: empty; the run wrote no metrics (it stopped at once); {rerun}")
            missing = [name for name in METRIC_FIELDS if name not in header]
            if missing or len(set(header)) != len(header):
                what = f"lacks the column(s) {', '.join(missing)}" if missing else "names a column twice"
                raise ReportError(f"{path}:1: the header {what}; it should be {','.join(METRIC_FIELDS)}; {rerun}")
            for values in reader:
                line = reader.line_num
                if not values:
                    continue  # a blank line
                if len(values) != len(header):
                    raise ReportError(
                        f"{path}:{line}: {len(values)} values where the header has {len(header)} columns (a row "
                        f"cut short, or two rows run together); delete or repair the line, or {rerun}"
                    )
                row = _typed_row(path, line, dict(zip(header, values, strict=True)), rerun)
                key = (row["event"], row["phase"], row["evaluations"])
                if key in seen:
                    raise ReportError(
                        f"{path}:{line}: repeats line {seen[key]} (event {row['event']}, phase {row['phase']}, "
                        f"{row['evaluations']} evaluations); every row must appear once: delete the repeated "
                        f"line, or {rerun}"
                    )
                seen[key] = line
                _check_order(path, line, row, rows[-1] if rows else None, lines[-1] if lines else 0, config, rerun)
                rows.append(row)
                lines.append(line)
    except UnicodeDecodeError:
        raise ReportError(f"{path}: not a text file (it is not UTF-8); {rerun}") from None
    except csv.Error as error:
        raise ReportError(f"{path}:{line + 1}: not readable as CSV ({error}); {rerun}") from None
    except OSError as error:
        raise ReportError(
            f"{path}: cannot be read ({error.strerror or error}); check its permissions, {_leave_out(directory)}"
        ) from None
    if not rows:
        raise ReportError(f"{path}: a header but no rows; the run wrote no metrics (it stopped at once); {rerun}")
    return rows


def _typed_row(path: Path, line: int, row: dict[str, str], rerun: str) -> dict[str, Any]:
    typed: dict[str, Any] = {}
    for name in METRIC_FIELDS:
        text = row[name]
        where = f"{path}:{line}: {name}"
        if name == "event":
            if text not in EVENTS:
                raise ReportError(f"{where} is {text[:40]!r}, not one of {', '.join(EVENTS)}; {rerun}")
            typed[name] = text
        elif name in WHOLE_FIELDS:
            try:
                value = int(text)
            except ValueError:
                value = -1
            if value < 0:
                raise ReportError(f"{where} is {text[:40]!r}, not a whole number of 0 or more; {rerun}")
            typed[name] = value
        else:
            try:
                number = float(text)
            except ValueError:
                raise ReportError(f"{where} is {text[:40]!r}, not a number; {rerun}") from None
            if name == "max_fitness":  # -inf: an archive that extinction emptied
                bad = math.isnan(number) or number == math.inf
            elif name == "coverage":
                bad = not 0 <= number <= 100
            elif name == "alpha":
                bad = not (math.isfinite(number) and number > 0)
            else:
                bad = not math.isfinite(number)
            if bad:
                allowed = {
                    "max_fitness": "a number or -inf",
                    "coverage": "a percentage from 0 to 100",
                    "alpha": "a finite number above 0",
                }.get(name, "a finite number")
                raise ReportError(f"{where} is {text[:40]!r}, but must be {allowed}; {rerun}")
            typed[name] = number
    return typed


def _check_order(
    path: Path,
    line: int,
    row: dict[str, Any],
    previous: dict[str, Any] | None,
    previous_line: int,
    config: RunConfig,
    rerun: str,
) -> None:
    """A row follows the one before as the runner writes them."""
    where = f"{path}:{line}"
    if row["generation"] > config.generations:
        raise ReportError(
            f"{where}: generation {row['generation']}, but config.json gives the run {config.generations} "
            f"generations; the two files are from different runs: {rerun}"
        )
    if row["phase"] >= config.num_phases:
        raise ReportError(
            f"{where}: phase {row['phase']}, but config.json gives the run {config.num_phases} phases "
            f"(0 to {config.num_phases - 1}); the two files are from different runs: {rerun}"
        )
    if previous is None:
        if row["event"] != "init" or row["generation"] != 0:
            raise ReportError(
                f"{where}: the first row must be generation 0's init row, not generation {row['generation']}'s "
                f"{row['event']} row; the start of the file is missing: {rerun}"
            )
        return
    expected = previous["generation"] + (0 if row["event"] == "reevaluate" else 1)
    if row["event"] == "init" or row["generation"] != expected or row["phase"] < previous["phase"]:
        raise ReportError(
            f"{where}: generation {row['generation']} ({row['event']}, phase {row['phase']}) cannot follow "
            f"generation {previous['generation']} (line {previous_line}, phase {previous['phase']}); rows are "
            f"missing or out of order: {rerun}"
        )
    if row["evaluations"] < previous["evaluations"]:
        raise ReportError(
            f"{where}: {row['evaluations']} evaluations, fewer than the {previous['evaluations']} of line "
            f"{previous_line}; rows are out of order: {rerun}"
        )


def read_final_archive(directory: Path, config: RunConfig) -> FinalArchive:
    """A finished run's archive.npz, checked: it loads, holds every array with the shapes the
    run's config gives (C cells, D descriptors, a policy per cell), and its values agree
    (fitness finite or -inf for an empty cell, `filled` where it is finite). Shapes are read
    from the arrays' headers first; the policies are checked by their shapes only, not read."""
    from smol_dsl.tasks import descriptor_bounds

    path = Path(directory) / "archive.npz"
    again = f"rerun the run (or copy the directory again if it was copied), {_leave_out(directory)}"
    if not path.is_file():
        raise ReportError(
            f"{path}: missing, though metrics.csv reaches the last generation: the run stopped before writing "
            f"its final archive; resume it with `smol-dsl run ... --resume` (or `sweep ... --resume`), which "
            f"writes it, {_leave_out(directory)}"
        )
    cells = config.num_centroids
    size = len(descriptor_bounds(config.task)[0])
    expected = {"fitnesses": (cells,), "descriptors": (cells, size), "centroids": (cells, size), "filled": (cells,)}

    def check(name: str, shape: tuple[int, ...], dtype: np.dtype) -> None:
        if name.startswith("genotypes/"):
            if shape[:1] != (cells,):
                raise ReportError(f"{path}: {name} has shape {shape}, not one policy per cell ({cells}, ...); {again}")
            return
        kind = np.bool_ if name == "filled" else np.floating
        if shape != expected[name] or not np.issubdtype(dtype, kind):
            raise ReportError(
                f"{path}: {name} is a {dtype} array of shape {shape}, but config.json ({cells} cells, "
                f"{config.task}'s {size} descriptors) gives {'bool' if name == 'filled' else 'float'} of shape "
                f"{expected[name]}; {again}"
            )

    with _reading_archive(path, again):
        with zipfile.ZipFile(path) as bundle:
            headers = {
                name.removesuffix(".npy"): _npy_header(bundle, name)
                for name in bundle.namelist()
                if name.endswith(".npy")
            }
    lacking = [name for name in ARCHIVE_ARRAYS if name not in headers]
    lacking += [] if any(name.startswith("genotypes/") for name in headers) else ["genotypes/..."]
    if lacking:
        raise ReportError(f"{path}: lacks the array(s) {', '.join(lacking)}; {again}")
    policies = [name for name in headers if name.startswith("genotypes/")]
    for name in [*ARCHIVE_ARRAYS, *policies]:  # before reading anything: a damaged header may claim any size
        if headers[name] is not None:
            check(name, *headers[name])
    with _reading_archive(path, again), np.load(path, allow_pickle=False) as data:
        arrays = {name: np.asarray(data[name]) for name in ARCHIVE_ARRAYS}
    for name, array in arrays.items():
        check(name, array.shape, array.dtype)
    fitnesses, filled = arrays["fitnesses"], arrays["filled"]
    if np.isnan(fitnesses).any() or (fitnesses == np.inf).any():
        raise ReportError(f"{path}: a fitness is NaN or +inf; {again}")
    if not np.array_equal(filled, fitnesses > -np.inf):
        raise ReportError(f"{path}: `filled` disagrees with the fitnesses (-inf marks an empty cell); {again}")
    if not np.isfinite(arrays["centroids"]).all() or not np.isfinite(arrays["descriptors"][filled]).all():
        raise ReportError(f"{path}: a centroid or a filled cell's descriptor is not finite; {again}")
    return FinalArchive(**arrays)


@contextlib.contextmanager
def _reading_archive(path: Path, again: str) -> Iterator[None]:
    """Turn what reading a damaged or unreadable archive raises into a ReportError."""
    try:
        yield
    except OSError as error:
        raise ReportError(
            f"{path}: cannot be read ({error.strerror or error}); check its permissions, {_leave_out(path.parent)}"
        ) from None
    except Exception as error:  # zipfile.BadZipFile, EOFError, ValueError...: a file cut short or damaged
        raise ReportError(
            f"{path}: not a readable archive ({type(error).__name__}: {error}); it is damaged or cut short "
            f"(a full disk, or an unfinished copy): {again}"
        ) from None


def _npy_header(bundle: zipfile.ZipFile, name: str) -> tuple[tuple[int, ...], np.dtype] | None:
    """The shape and dtype in an .npy member's header, without reading its data (None: a
    header version this does not read; the array is checked once loaded)."""
    with bundle.open(name) as member:
        version = np.lib.format.read_magic(member)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(member)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(member)
        else:
            return None
        return shape, dtype


def load_runs(paths: Sequence[str | Path]) -> dict[str, list[RunRecord]]:
    """Finished runs below `paths`, grouped by schedule name in the paper's order.

    Every run directory is read and checked first (`read_run`); then refuses (ReportError)
    no runs, unfinished runs, runs of several tasks or settings, two schedules with one name,
    and a (schedule, seed) given twice, seeds that JAX takes as equal (S and S + 2**32) included.
    """
    directories = find_run_directories(paths)
    if not directories:
        raise ReportError(
            f"no run directories in {', '.join(str(p) for p in paths)} (a run directory holds config.json "
            "and metrics.csv); make some with `smol-dsl sweep` or `smol-dsl run`"
        )
    runs, problems = [], []
    for directory in directories:
        try:
            runs.append(read_run(directory))
        except ReportError as error:
            problems.append(str(error))
    if problems:
        if len(problems) == 1:
            raise ReportError(problems[0])
        shown = "\n  ".join(problems[:MOST_PROBLEMS])
        more = f"\n  and {len(problems) - MOST_PROBLEMS} more" if len(problems) > MOST_PROBLEMS else ""
        raise ReportError(f"{len(problems)} of the {len(directories)} run directories cannot be used:\n  {shown}{more}")
    tasks = sorted({run.task for run in runs})
    if len(tasks) > 1:
        examples = "; ".join(f"{task}: {next(r.directory for r in runs if r.task == task)}" for task in tasks)
        raise ReportError(
            f"the runs are of different tasks ({', '.join(tasks)}), which cannot share a table ({examples}); "
            "report each task's directories separately"
        )
    unfinished = [run for run in runs if not run.finished]
    if unfinished:
        raise ReportError(
            f"{len(unfinished)} run(s) have not finished, e.g. {unfinished[0].directory} (generation "
            f"{unfinished[0].final['generation']} of {unfinished[0].config.generations}); finish them with "
            "`smol-dsl sweep ... --resume` or `smol-dsl run ... --resume`, or leave them out"
        )
    reference = runs[0]
    steps = _steps(reference)
    for run in runs[1:]:
        if run.settings != reference.settings:
            differing = sorted(k for k in run.settings if run.settings[k] != reference.settings.get(k))
            raise ReportError(
                f"{run.directory} and {reference.directory} were run with different settings "
                f"({', '.join(differing)}); only runs with the same settings can be compared"
            )
        if _steps(run) != steps:
            raise ReportError(
                f"{run.directory / 'metrics.csv'} ({len(run.rows)} rows) and {reference.directory / 'metrics.csv'} "
                f"({len(reference.rows)} rows) log different generations and phases although their runs have the "
                "same settings; one of them was cut or edited: rerun it, or move it out of the directories you "
                "report on"
            )
    groups: dict[str, list[RunRecord]] = {}
    for run in runs:
        group = groups.setdefault(run.schedule, [])
        if group and group[0].schedule_source != run.schedule_source:
            raise ReportError(
                f"two different schedules are both named {run.schedule!r} ({group[0].directory} and "
                f"{run.directory}); give them different `name`s"
            )
        twin = next((other for other in group if other.seed % SEED_MODULUS == run.seed % SEED_MODULUS), None)
        if twin is not None:
            same = (
                f"seed {run.seed} is there twice"
                if twin.seed == run.seed
                else f"seeds {twin.seed} and {run.seed} are the same run (JAX takes seeds modulo 2**32)"
            )
            raise ReportError(
                f"{run.schedule} {same} ({twin.directory} and {run.directory}); each run must count once: "
                "leave one of them out"
            )
        group.append(run)
    ordered = sorted(groups, key=lambda name: (ORDER.index(name) if name in ORDER else len(ORDER), name))
    return {name: sorted(groups[name], key=lambda r: r.seed) for name in ordered}


def _steps(run: RunRecord) -> list[tuple[int, int, int]]:
    """What a run's rows log, whatever its results: (generation, phase, evaluations) per row."""
    return [(row["generation"], row["phase"], row["evaluations"]) for row in run.rows]


def final_scores(groups: dict[str, list[RunRecord]], metric: str) -> dict[str, np.ndarray]:
    """Each schedule's final value of the metric, one per run (seed order)."""
    if metric not in METRICS:
        raise ReportError(f"unknown metric {metric!r}; the metrics are {', '.join(METRICS)}")
    return {name: np.asarray([run.final[metric] for run in runs], dtype=float) for name, runs in groups.items()}


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
        """Warnings about the table's power: with few runs no p-value can fall below 0.05."""
        notes = []
        for row in self.rows:
            for column in self.columns:
                if row != column and smallest_p(self.runs[column], self.runs[row]) >= SIGNIFICANCE:
                    notes.append(
                        f"{column} ({self.runs[column]} runs) vs {row} ({self.runs[row]} runs): the smallest "
                        f"possible p-value is {smallest_p(self.runs[column], self.runs[row]):.3g}, so this pair "
                        f"cannot reach p < {SIGNIFICANCE}; run more seeds (the paper used 7 to 10)"
                    )
        return notes

    @property
    def best(self) -> set[str]:
        """The schedules with the highest median (several when they tie)."""
        top = max(self.medians[name] for name in self.rows)
        return {name for name in self.rows if self.medians[name] == top}

    def markdown(self) -> str:
        header = ["schedule", "runs", "median score", *(f"p: {_markdown_escape(c)} better" for c in self.columns)]
        lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + ["---:"] * (len(header) - 1)) + "|"]
        for row in self.rows:
            median = _number(self.medians[row])
            cells = [_markdown_escape(row), str(self.runs[row]), f"**{median}**" if row in self.best else median]
            for column in self.columns:
                p = self.pvalues[row][column]
                cells.append("-" if p is None else (f"**{p:.3e}**" if p < SIGNIFICANCE else f"{p:.3e}"))
            lines.append("| " + " | ".join(cells) + " |")
        return "\n".join(lines) + "\n"

    def latex(self) -> str:
        columns = len(self.columns)
        lines = [
            "\\begin{tabular}{l|c|" + "c|" * columns + "}",
            "\\toprule",
            f" & Median & \\multicolumn{{{columns}}}{{c|}}{{p-values}} \\\\",
            " & score & " + " & ".join(_latex_escape(c) for c in self.columns) + " \\\\",
            "\\midrule",
        ]
        for row in self.rows:
            median = _number(self.medians[row])
            cells = [_latex_escape(row), f"\\textbf{{{median}}}" if row in self.best else median]
            for column in self.columns:
                p = self.pvalues[row][column]
                cells.append("-" if p is None else (f"\\textbf{{{p:.3e}}}" if p < SIGNIFICANCE else f"{p:.3e}"))
            lines.append(" & ".join(cells) + " \\\\")
        lines += ["\\bottomrule", "\\end{tabular}"]
        return "\n".join(lines) + "\n"


def smallest_p(runs_a: int, runs_b: int) -> float:
    """The smallest p-value an exact one-sided U test can give with these sample sizes."""
    return 1 / math.comb(runs_a + runs_b, runs_a)


def _number(value: float) -> str:
    return f"{value:.1f}"


def _markdown_escape(text: str) -> str:
    """A name as one table cell: a | would start another cell, a line break another row."""
    return "".join(char if char.isprintable() else " " for char in text).replace("|", "\\|")


LATEX_SPECIAL = {
    **{char: "\\" + char for char in "&%$#_{}"},
    "\\": "\\textbackslash{}",
    "^": "\\textasciicircum{}",
    "~": "\\textasciitilde{}",
}


def _latex_escape(text: str) -> str:
    """A name as LaTeX text: its special characters escaped, control characters as spaces."""
    return "".join(LATEX_SPECIAL.get(char, char if char.isprintable() else " ") for char in text)


def pvalue_table(groups: dict[str, list[RunRecord]], metric: str | None = None) -> PValueTable:
    """The paper's table: rows every schedule, columns the SMOL curricula present (all
    schedules when none is), each cell the one-sided Mann-Whitney U p-value of "column
    better than row" on final scores."""
    from scipy.stats import mannwhitneyu

    task = next(iter(groups.values()))[0].task
    metric = metric or DEFAULT_METRIC[task]
    scores = final_scores(groups, metric)
    names = list(groups)
    columns = [name for name in COLUMNS if name in groups] or names
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
        runs={name: len(groups[name]) for name in names},
        pvalues=pvalues,
    )


# ---------------------------------------------------------------------------- figures
def figure_groups(names: Sequence[str]) -> dict[str, list[str]]:
    """The paper's two figures: main results (the curricula and vanilla, and any other
    schedule) and ablations (SMOL against random and extinction), where present."""
    ablations = [name for name in names if name in ABLATIONS]
    main = [name for name in names if name not in ABLATIONS]
    figures = {}
    if main:
        figures["main-results"] = main
    if ablations:
        figures["ablation-results"] = (["SMOL"] if "SMOL" in names else []) + ablations
    return figures


def results_figure(groups: dict[str, list[RunRecord]], names: Sequence[str], title: str) -> Any:
    """Median (line) and interquartile range (band) over seeds of max fitness, coverage
    and QD score against training evaluations, one colour per schedule (and, past 20, dash
    patterns; past 10 schedules the legend goes below the plots); a dashed line from where
    alpha is 1 for every schedule shown."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from smol_dsl.plotting import LEGEND_INSIDE, legend_label, place_legend, series_styles

    figure = Figure(figsize=(13, 3.8), layout="constrained")
    axes = figure.subplots(1, len(METRICS))
    if len(names) <= LEGEND_INSIDE:  # the paper's colours for the paper's schedules
        colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
        styles = [
            {"color": ORDER_COLORS.get(name, colors[(i + len(ORDER_COLORS)) % len(colors)])}
            for i, name in enumerate(names)
        ]
    else:
        styles = series_styles(len(names))
    # where alpha is 1 for every schedule shown (the paper's fair-comparison line)
    alpha_one = max((x for name in names if (x := groups[name][0].alpha_one_evaluations()) is not None), default=None)
    for ax, metric in zip(axes, METRICS, strict=True):
        for name, style in zip(names, styles, strict=True):
            runs = groups[name]
            evaluations = runs[0].curve(metric)[0]
            values = np.stack([run.curve(metric)[1] for run in runs])
            values[~np.isfinite(values)] = np.nan  # max fitness of an archive emptied by extinction
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a moment when every archive is empty
                low, median, high = np.nanpercentile(values, [25, 50, 75], axis=0)
            ax.plot(evaluations, median, lw=1.5, label=legend_label(f"{name} ({len(runs)})"), **style)
            ax.fill_between(evaluations, low, high, color=style["color"], alpha=0.2, lw=0)
        if alpha_one is not None:
            ax.axvline(alpha_one, color="0.3", ls="--", lw=1.0)
        ax.set_xlabel("evaluations")
        ax.set_ylabel(METRIC_LABELS[metric])
        ax.grid(alpha=0.25)
    place_legend(figure, axes[0], title="schedule (runs)", title_fontsize=8)
    figure.suptitle(title)
    return figure


ORDER_COLORS = {
    "Vanilla MAP-Elites": "#4d4d4d",
    "SMOL": "#1f77b4",
    "SMOL-Reverse": "#ff7f0e",
    "SMOL-Human": "#2ca02c",
    "Random": "#9467bd",
    "Extinction 5%": "#8c564b",
    "Extinction 10%": "#e377c2",
    "Extinction 50%": "#bcbd22",
}
ARCHIVE_COLUMNS = 4
"""Final archives per row of archives.png."""


def median_run(runs: Sequence[RunRecord], metric: str) -> RunRecord:
    """The run with the median final score (the lower one for an even number of runs)."""
    ranked = sorted(runs, key=lambda run: run.final[metric])
    return ranked[(len(ranked) - 1) // 2]


def archives_figure(groups: dict[str, list[RunRecord]], metric: str, title: str) -> Any:
    """Final archives, one per schedule, in rows of up to ARCHIVE_COLUMNS: the run with the
    median final score (the lower one for an even number of runs), on one colour scale."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    from smol_dsl.plotting import legend_label
    from smol_dsl.runner.figures import draw_archive
    from smol_dsl.tasks import descriptor_bounds

    chosen = {name: median_run(runs, metric) for name, runs in groups.items()}
    archives = {
        name: run.archive if run.archive is not None else read_final_archive(run.directory, run.config)
        for name, run in chosen.items()
    }
    filled = np.concatenate([a.fitnesses[a.filled] for a in archives.values()])
    vmin, vmax = (float(filled.min()), float(filled.max())) if filled.size else (None, None)
    low, high = descriptor_bounds(next(iter(chosen.values())).task)
    columns = min(len(archives), ARCHIVE_COLUMNS)
    rows = math.ceil(len(archives) / columns)
    figure = Figure(figsize=(3.6 * columns + 1.0, 3.6 * rows + 0.4), layout="constrained")
    axes = np.atleast_1d(figure.subplots(rows, columns)).reshape(-1)
    shown = None
    for ax, (name, archive) in zip(axes, archives.items(), strict=False):
        shown = draw_archive(ax, archive.centroids, archive.fitnesses, low, high, pixels=300, vmin=vmin, vmax=vmax)
        coverage = 100 * archive.filled.mean()
        ax.set_title(f"{legend_label(name)}, seed {chosen[name].seed}\ncoverage {coverage:.1f}%", fontsize=9)
    for ax in axes[len(archives) :]:
        ax.set_axis_off()
    if shown is not None:
        figure.colorbar(shown, ax=list(axes[: len(archives)]), label="fitness", shrink=min(1.0, 2.5 / rows))
    figure.suptitle(title)
    return figure


# ---------------------------------------------------------------------------- report
@dataclass(frozen=True)
class Report:
    """What `write_report` wrote."""

    table: PValueTable
    files: list[Path]


def earlier_report(out_dir: str | Path) -> list[str]:
    """The report files already in out_dir (none if it does not exist)."""
    out = Path(out_dir)
    return [name for name in REPORT_FILES if os.path.lexists(out / name)] if out.is_dir() else []


def check_output_directory(out_dir: str | Path, force: bool = False) -> list[str]:
    """Refuse (ReportError) an output directory that is a file, cannot be made or written,
    or holds an earlier report (unless `force`). Returns the earlier report's files."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ReportError(
            f"{out} is a file, not a directory: the report is several files (table.md, pvalues.tex, scores.csv, "
            "figures) and -o names the directory they go into; give another -o"
        )
    existing = out
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise ReportError(f"cannot create {out}: {existing} is a file, not a directory; give another -o")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ReportError(f"cannot write into {existing} (permission denied); give another -o")
    blocked = [name for name in REPORT_FILES if (out / name).is_dir()]
    if blocked:
        raise ReportError(
            f"{out / blocked[0]} is a directory, where the report writes a file; move it, or give another -o"
        )
    earlier = earlier_report(out)
    if earlier and not force:
        raise ReportError(
            f"{out} already holds a report ({', '.join(earlier)}); give --force to replace it "
            "(force=True in Python), or another output directory with -o"
        )
    return earlier


def render_report(groups: dict[str, list[RunRecord]], table: PValueTable) -> dict[str, bytes]:
    """Every file of the report by name, in memory: table.md, pvalues.tex, scores.csv and
    the figures (PNG and PDF)."""
    files: dict[str, bytes] = {}
    label = METRIC_LABELS[table.metric]
    caption = (
        f"{table.task} ({label}): median final scores and p-values of one-sided Mann-Whitney U tests, with "
        f"the alternative that the column schedule is better than the row schedule; p < {SIGNIFICANCE} in bold."
    )
    files["table.md"] = f"{caption}\n\n{table.markdown()}".encode()
    files["pvalues.tex"] = f"% {caption}\n{table.latex()}".encode()
    scores = io.StringIO(newline="")
    writer = csv.writer(scores)
    writer.writerow(["schedule", "seed", *METRICS, "directory"])
    for name, runs in groups.items():
        for run in runs:
            writer.writerow([name, run.seed, *(run.final[m] for m in METRICS), str(run.directory)])
    files["scores.csv"] = scores.getvalue().encode()
    figures = {}
    for stem, names in figure_groups(list(groups)).items():
        what = "main results" if stem == "main-results" else "ablations"
        figures[stem] = results_figure(groups, names, f"{table.task}: {what} (median and IQR over seeds)")
    if _descriptor_size(groups) == 2:
        by = table.metric.replace("_", " ")
        figures["archives"] = archives_figure(
            groups, table.metric, f"{table.task}: final archives (median run by {by})"
        )
    for stem, figure in figures.items():
        for suffix in ("png", "pdf"):
            image = io.BytesIO()
            figure.savefig(image, format=suffix, dpi=130)
            files[f"{stem}.{suffix}"] = image.getvalue()
    return files


def write_files(out_dir: str | Path, files: dict[str, bytes], remove: Sequence[str] = ()) -> list[Path]:
    """Write files into out_dir (made if need be), each atomically: all are written to
    temporary files in out_dir first and then renamed into place, so a failure (a full disk)
    leaves no file half-written and, before the renames, changes nothing; temporary files are
    removed whatever happens. Then remove the files named in `remove`."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ReportError(f"cannot create {out} ({error.strerror or error}); give another -o") from None
    temporaries: dict[str, Path] = {}
    name = ""
    try:
        for name, data in files.items():
            temporaries[name] = out / f".{name}.{os.getpid()}.tmp"
            _write_bytes(temporaries[name], data)
        for name, temporary in temporaries.items():
            os.replace(temporary, out / name)
        for name in remove:
            (out / name).unlink(missing_ok=True)
    except OSError as error:
        raise ReportError(
            f"cannot write {out / name} ({error.strerror or error}); free some space or give another -o"
        ) from None
    finally:
        for temporary in temporaries.values():
            try:
                temporary.unlink(missing_ok=True)
            except OSError:
                pass
    return [out / name for name in files]


def _write_bytes(path: Path, data: bytes) -> None:
    with open(path, "wb") as file:
        file.write(data)


def write_report(
    paths: Sequence[str | Path], out_dir: str | Path, metric: str | None = None, *, force: bool = False
) -> Report:
    """Table (table.md, pvalues.tex), final scores (scores.csv) and figures (PNG and PDF)
    of the runs below `paths`, written into out_dir.

    Every run is read and checked, and every file drawn, before the first file is written;
    each file is written atomically. An out_dir that already holds a report is refused
    (ReportError) unless `force`, which replaces it (files of the earlier report that this one
    does not write, such as an ablation figure, are removed)."""
    earlier = check_output_directory(out_dir, force)
    groups = load_runs(paths)
    table = pvalue_table(groups, metric)
    files = render_report(groups, table)
    written = write_files(out_dir, files, remove=[name for name in earlier if name not in files])
    return Report(table, written)


def _descriptor_size(groups: dict[str, list[RunRecord]]) -> int:
    from smol_dsl.tasks import descriptor_bounds

    return len(descriptor_bounds(next(iter(groups.values()))[0].task)[0])
