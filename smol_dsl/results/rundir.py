"""The run directory: the one definition of what `smol-dsl run` and `sweep` write and what
`smol-dsl report` reads.

File names are the `*_FILE` constants (`FILES` says what each holds). The columns of
metrics.csv are `METRICS_SCHEMA`, one `Column` per column (name, Python type, meaning, the
values it may take); the CSV header, the row builder, the writer and the typed, checked
reader are all derived from it, so a new float column is one line there (and the runner
giving its value).

Writing, for the runner (numpy only; every file is written atomically, and an OSError names
the file that could not be written):

    write_run_files(directory, config, schedule) -> list[Path]   # config.json, schedule.sched, certificate.*
    log = MetricsLog(directory / METRICS_FILE, rows)   # exactly `rows`, written atomically
    log.append(metrics_row(generation=..., phase=..., alpha=..., event="train", ...))
    write_archive(directory / ARCHIVE_FILE, arrays)    # {"genotypes/<param path>": (C, ...), "fitnesses",
                                                       #  "descriptors", "centroids"}; `filled` is derived
    atomic_write(path, write), write_npz(path, arrays)
    alpha_one_evaluations(rows, first_tail_phase)

Reading, for the report and for users:

    read_run(directory) -> RunRecord     # every file checked; a RunDirectoryError names file and line
    read_config, read_certificate, read_metrics, read_final_archive
    load_archive(path) -> Archive        # the final archive with its policies, as nested dicts

Nothing here imports JAX, Brax, QDax or Flax.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import json
import math
import os
import zipfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from smol_dsl.errors import UserInputError
from smol_dsl.runner.config import RunConfig
from smol_dsl.tasks import task_spec

if TYPE_CHECKING:
    from smol_dsl import Schedule

# ---------------------------------------------------------------------------- file names
CONFIG_FILE = "config.json"
SCHEDULE_FILE = "schedule.sched"
CERTIFICATE_FILE = "certificate.json"
CERTIFICATE_TEXT_FILE = "certificate.txt"
METRICS_FILE = "metrics.csv"
CHECKPOINT_FILE = "checkpoint.npz"
ARCHIVE_FILE = "archive.npz"
METRICS_FIGURE = "metrics.png"
ARCHIVE_FIGURE = "archive.png"
LOCK_FILE = ".smol-dsl.lock"
SWEEP_FILE = "sweep.json"
SWEEP_CHECKPOINT_FILE = "sweep-checkpoint.npz"

FILES = (
    (CONFIG_FILE, "the resolved settings (`RunConfig`)"),
    (SCHEDULE_FILE, "the schedule's source"),
    (CERTIFICATE_FILE, "what was proven about the schedule, with its `name` and `tail_start` (where α = 1 for good)"),
    (CERTIFICATE_TEXT_FILE, "the same certificate, as `smol-dsl check` prints it"),
    (METRICS_FILE, "one row per generation and per re-evaluation (columns below)"),
    (CHECKPOINT_FILE, "the state at the last checkpointed phase boundary (for `--resume`)"),
    (
        ARCHIVE_FILE,
        "the final archive: `genotypes/<parameter path>` (C, ...), `fitnesses` (C,), `descriptors` (C, D), "
        "`centroids` (C, D), `filled` (C,); an empty cell's fitness is −inf",
    ),
    (METRICS_FIGURE, "max fitness, coverage, QD score and every scheduled channel's factor over training evaluations"),
    (
        ARCHIVE_FIGURE,
        "the final archive: a 2-D map of the CVT cells coloured by their elites' fitness (1 descriptor: fitness "
        "along it; more than 2: the best elite over the first two descriptors)",
    ),
    (LOCK_FILE, "the lock of the process writing the directory: its pid and host"),
)
"""Every file of a run directory and what it holds, in the order the runner writes them."""
SWEEP_FILES = (
    (SWEEP_FILE, "the sweep's settings, schedules and seeds"),
    (SWEEP_CHECKPOINT_FILE, "every run's state at the last checkpointed phase boundary, stacked"),
)
"""A sweep directory's own files, beside one run directory per (schedule, seed)."""
RUN_MARKERS = (SCHEDULE_FILE, CERTIFICATE_FILE, ARCHIVE_FILE, CHECKPOINT_FILE)
"""Besides metrics.csv, files that make a directory with a config.json a run directory."""


class RunDirectoryError(UserInputError):
    """A run directory whose files cannot be used: the message names the file (and line),
    what is wrong with it and what to do."""


def _leave_out(directory: Path) -> str:
    return f"or move {directory} out of the directories you report on"


# ---------------------------------------------------------------------------- metrics schema
EVENTS = ("init", "train", "reevaluate", "reseed")
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

    def __post_init__(self) -> None:
        if self.type not in (int, float, str):
            raise TypeError(f"column {self.name}: the type must be int, float or str, not {self.type!r}")

    @property
    def axis_label(self) -> str:
        return self.label or self.name.replace("_", " ")

    @property
    def values(self) -> str:
        """The values the column may take, in words."""
        if self.type is int:
            return "a whole number of 0 or more"
        if self.type is str:
            return ", ".join(self.choices) if self.choices else "text"
        return self.expected

    def convert(self, value: Any) -> Any:
        """A value as the row writer writes it (a NumPy or JAX scalar becomes a Python one)."""
        return self.type(value)

    def parse(self, text: str) -> Any:
        """The typed value of one CSV cell; a ValueError saying what is wrong ("is 'x', not ...")."""
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
        """A CSV row's cells typed; a ValueError naming the column ("alpha is 'x', not a number")."""
        typed = {}
        for column in self.columns:
            try:
                typed[column.name] = column.parse(texts[column.name])
            except ValueError as error:
                raise ValueError(f"{column.name} {error}") from None
        return typed

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
    )
)
"""metrics.csv's columns. `event` is `init` (generation 0's random population), `train` (a
generation), `reevaluate` (the archive re-scored at a phase boundary) or `reseed` (a
generation that re-seeded an archive extinction emptied)."""
METRIC_FIELDS = METRICS_SCHEMA.names
"""metrics.csv's header."""
SCORES = ("max_fitness", "coverage", "qd_score")
"""The columns that score an archive: what a report compares and figures draw."""


def channel_column(name: str) -> Column:
    """The metrics.csv column of a scheduled channel other than the actuators' gear (which is
    `alpha`): named as the channel (`mass`, `gear[left_leg]`), its factor in the phase."""
    return Column(name, float, f"the phase's {name} factor", valid=_positive, expected="a finite number above 0")


def metrics_schema(channels: Sequence[str] = ()) -> MetricsSchema:
    """METRICS_SCHEMA with one column per channel other than plain `gear` (whose factor is
    `alpha`), right after `alpha`, in the order given."""
    extra = tuple(channel_column(name) for name in channels if name not in ("gear", "alpha"))
    if not extra:
        return METRICS_SCHEMA
    at = METRICS_SCHEMA.names.index("alpha") + 1
    return MetricsSchema(METRICS_SCHEMA.columns[:at] + extra + METRICS_SCHEMA.columns[at:])


def schema_of_header(header: Sequence[str]) -> MetricsSchema:
    """The schema of a metrics.csv with this header: METRICS_SCHEMA and a column for every
    header name that is a channel's (other columns are ignored, as before)."""
    from smol_dsl.language.channels import Channel

    channels = []
    for name in header:
        if name in METRICS_SCHEMA.names:
            continue
        try:
            channels.append(Channel.parse(name).name)
        except ValueError:
            continue
    return metrics_schema(channels)


def metrics_row(schema: MetricsSchema = METRICS_SCHEMA, **values: Any) -> dict[str, Any]:
    """A metrics.csv row of `schema`: every column, typed (`float(jax_scalar)` done here)."""
    return schema.row(**values)


# ---------------------------------------------------------------------------- writing
def atomic_write(path: Path, write: Callable[[IO[bytes]], Any]) -> None:
    """Call write(file) on a temporary file beside `path`, fsync it, and rename it over path.

    If anything fails (a full disk, say), the temporary file is removed and `path` is left as
    it was; an OSError is raised with `filename` set to `path`, whatever file the OS named.
    """
    path = Path(path)
    temporary = path.with_name(f"{path.name}.{os.getpid()}.tmp")  # processes may share a directory
    try:
        with open(temporary, "wb") as file:
            write(file)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException as error:
        with contextlib.suppress(OSError):
            temporary.unlink(missing_ok=True)
        if isinstance(error, OSError) and error.filename != str(path):
            raise OSError(error.errno, error.strerror or str(error), str(path)) from error
        raise
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)


def write_npz(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    """Write arrays atomically as an uncompressed `.npz`."""
    atomic_write(path, lambda file: np.savez(file, **arrays))


def write_text(path: Path, text: str) -> None:
    """Write a UTF-8 text atomically."""
    atomic_write(path, lambda file: file.write(text.encode()))


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


def certificate_record(schedule: Schedule) -> dict[str, Any]:
    """certificate.json's contents: the schedule's name, the start of its α = 1 tail and
    its certificate."""
    record = {"name": schedule.name, "tail_start": float(schedule.tail_start), **schedule.certificate.to_dict()}
    record["final_body"] = {channel.name: value for channel, value in schedule.final_body.items()}
    record["channels"] = {channel.name: cert.to_dict() for channel, cert in schedule.certificates.items()}
    return record


def certificate_text(schedule: Schedule) -> str:
    """The certificate as `smol-dsl check` prints it: one per scheduled channel."""
    certificates = schedule.certificates
    if len(certificates) == 1:
        return str(next(iter(certificates.values())))
    return "\n".join(f"channel {channel.name}:\n{cert}" for channel, cert in certificates.items())


def write_run_files(directory: Path, config: RunConfig, schedule: Schedule) -> list[Path]:
    """A new run's config.json, schedule.sched, certificate.json and certificate.txt, each
    written atomically. If one cannot be written (a full disk), those written are removed and
    the OSError, naming the file, is raised: nothing is left half set up."""
    texts = {
        CONFIG_FILE: config.to_json(),
        SCHEDULE_FILE: schedule.source,
        CERTIFICATE_FILE: json.dumps(certificate_record(schedule), indent=2),
        CERTIFICATE_TEXT_FILE: certificate_text(schedule),
    }
    written: list[Path] = []
    try:
        for name, text in texts.items():
            write_text(directory / name, text)
            written.append(directory / name)
    except BaseException:
        for path in written:
            with contextlib.suppress(OSError):
                path.unlink()
        raise
    return written


ARCHIVE_ARRAYS = ("fitnesses", "descriptors", "centroids", "filled")
"""archive.npz's arrays besides the policies (`genotypes/<parameter path>`)."""
GENOTYPES = "genotypes/"


def write_archive(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    """The final archive as `.npz`, atomically, from host arrays: `genotypes/<param path>`
    (C, ...), `fitnesses` (C,) or (C, 1), `descriptors` (C, D), `centroids` (C, D). Fitnesses
    are stored as (C,), and `filled` (C,) is where they are above -inf."""
    unknown = [name for name in arrays if not name.startswith(GENOTYPES) and name not in ARCHIVE_ARRAYS]
    if unknown:
        raise ValueError(f"write_archive: unknown array(s) {unknown}")
    fitnesses = np.asarray(arrays["fitnesses"]).reshape(-1)
    write_npz(path, {**arrays, "fitnesses": fitnesses, "filled": fitnesses > -np.inf})


def alpha_one_evaluations(rows: Sequence[Mapping[str, Any]], first_tail_phase: int) -> float | None:
    """Training evaluations at the start of the first phase of the alpha = 1 tail."""
    for row in rows:
        if row["phase"] >= first_tail_phase:
            return float(row["evaluations"])
    return None


def first_tail_phase(tail_start: float, num_phases: int) -> int:
    """The first phase k with k / num_phases >= tail_start (num_phases if none), robust to
    tail_start having been rounded to a float."""
    first = min(math.ceil(tail_start * num_phases), num_phases)
    while first > 0 and (first - 1) / num_phases >= tail_start:
        first -= 1
    while first < num_phases and first / num_phases < tail_start:
        first += 1
    return first


# ---------------------------------------------------------------------------- archives
@dataclass(frozen=True)
class Archive:
    """A saved archive: policy parameters as a nested dict (flax layout) and its scores."""

    genotypes: dict[str, Any]
    fitnesses: np.ndarray
    descriptors: np.ndarray
    centroids: np.ndarray
    filled: np.ndarray

    def elite(self, cell: int) -> dict[str, Any]:
        """The policy parameters in one cell, ready for `policy.apply(params, obs)`."""

        def take(node: Any) -> Any:
            if isinstance(node, Mapping):
                return {name: take(child) for name, child in node.items()}
            return node[cell]

        return take(self.genotypes)

    @property
    def best_cell(self) -> int:
        return int(np.argmax(self.fitnesses))


def load_archive(path: str | os.PathLike[str]) -> Archive:
    """Load `archive.npz` from a run directory (or its path)."""
    path = Path(path)
    if path.is_dir():
        path = path / ARCHIVE_FILE
    with np.load(path, allow_pickle=False) as data:
        genotypes: dict[str, Any] = {}
        for name in data.files:
            if not name.startswith(GENOTYPES):
                continue
            node = genotypes
            *parents, leaf = name.split("/")[1:]
            for part in parents:
                node = node.setdefault(part, {})
            node[leaf] = data[name]
        return Archive(genotypes=genotypes, **{name: data[name] for name in ARCHIVE_ARRAYS})


@dataclass(frozen=True)
class FinalArchive:
    """A run's final archive.npz without its policies: what the report reads and draws.
    `fitnesses` (C,), -inf in empty cells; `descriptors` and `centroids` (C, D); `filled` (C,)."""

    fitnesses: np.ndarray
    descriptors: np.ndarray
    centroids: np.ndarray
    filled: np.ndarray


def read_final_archive(directory: Path, config: RunConfig) -> FinalArchive:
    """A finished run's archive.npz, checked: it loads, holds every array with the shapes the
    run's config gives (C cells, D descriptors, a policy per cell), and its values agree
    (fitness finite or -inf for an empty cell, `filled` where it is finite). Shapes are read
    from the arrays' headers first; the policies are checked by their shapes only, not read."""
    path = Path(directory) / ARCHIVE_FILE
    again = f"rerun the run (or copy the directory again if it was copied), {_leave_out(directory)}"
    if not path.is_file():
        raise RunDirectoryError(
            f"{path}: missing, though {METRICS_FILE} reaches the last generation: the run stopped before writing "
            f"its final archive; resume it with `smol-dsl run ... --resume` (or `sweep ... --resume`), which "
            f"writes it, {_leave_out(directory)}"
        )
    cells = config.num_centroids
    size = task_spec(config.task).descriptor_size
    expected = {"fitnesses": (cells,), "descriptors": (cells, size), "centroids": (cells, size), "filled": (cells,)}

    def check(name: str, shape: tuple[int, ...], dtype: np.dtype) -> None:
        if name.startswith(GENOTYPES):
            if shape[:1] != (cells,):
                raise RunDirectoryError(
                    f"{path}: {name} has shape {shape}, not one policy per cell ({cells}, ...); {again}"
                )
            return
        kind = np.bool_ if name == "filled" else np.floating
        if shape != expected[name] or not np.issubdtype(dtype, kind):
            raise RunDirectoryError(
                f"{path}: {name} is a {dtype} array of shape {shape}, but {CONFIG_FILE} ({cells} cells, "
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
    lacking += [] if any(name.startswith(GENOTYPES) for name in headers) else ["genotypes/..."]
    if lacking:
        raise RunDirectoryError(f"{path}: lacks the array(s) {', '.join(lacking)}; {again}")
    policies = [name for name in headers if name.startswith(GENOTYPES)]
    for name in [*ARCHIVE_ARRAYS, *policies]:  # before reading anything: a damaged header may claim any size
        if headers[name] is not None:
            check(name, *headers[name])
    with _reading_archive(path, again), np.load(path, allow_pickle=False) as data:
        arrays = {name: np.asarray(data[name]) for name in ARCHIVE_ARRAYS}
    for name, array in arrays.items():
        check(name, array.shape, array.dtype)
    fitnesses, filled = arrays["fitnesses"], arrays["filled"]
    if np.isnan(fitnesses).any() or (fitnesses == np.inf).any():
        raise RunDirectoryError(f"{path}: a fitness is NaN or +inf; {again}")
    if not np.array_equal(filled, fitnesses > -np.inf):
        raise RunDirectoryError(f"{path}: `filled` disagrees with the fitnesses (-inf marks an empty cell); {again}")
    if not np.isfinite(arrays["centroids"]).all() or not np.isfinite(arrays["descriptors"][filled]).all():
        raise RunDirectoryError(f"{path}: a centroid or a filled cell's descriptor is not finite; {again}")
    return FinalArchive(**arrays)


@contextlib.contextmanager
def _reading_archive(path: Path, again: str) -> Iterator[None]:
    """Turn what reading a damaged or unreadable archive raises into a RunDirectoryError."""
    try:
        yield
    except OSError as error:
        raise RunDirectoryError(
            f"{path}: cannot be read ({error.strerror or error}); check its permissions, {_leave_out(path.parent)}"
        ) from None
    except Exception as error:  # zipfile.BadZipFile, EOFError, ValueError...: a file cut short or damaged
        raise RunDirectoryError(
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


# ---------------------------------------------------------------------------- reading
def read_text(path: Path) -> str:
    """A run directory's text file, or a RunDirectoryError saying why it cannot be used."""
    directory = path.parent
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RunDirectoryError(
            f"{path}: missing; every run directory holds it (the runner writes it first), so {directory} is "
            f"incomplete: rerun that run, {_leave_out(directory)}"
        ) from None
    except UnicodeDecodeError:
        raise RunDirectoryError(
            f"{path}: not a text file (it is not UTF-8); rerun that run, {_leave_out(directory)}"
        ) from None
    except OSError as error:
        raise RunDirectoryError(
            f"{path}: cannot be read ({error.strerror or error}); check its permissions, {_leave_out(directory)}"
        ) from None


CONFIG_TYPES = {"str": str, "int": int, "float": float, "tuple[int, ...]": list}
CONFIG_AT_LEAST_ONE = ("evaluations", "batch_size", "num_phases", "num_centroids", "episode_length")


def read_config(path: Path) -> RunConfig:
    """A run's config.json, checked: every setting present, of its type, and usable."""
    text = read_text(path)
    fix = f"this is not a {CONFIG_FILE} that smol-dsl wrote; rerun the run, {_leave_out(path.parent)}"
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as error:
        where = f":{error.lineno}" if isinstance(error, json.JSONDecodeError) else ""
        raise RunDirectoryError(f"{path}{where}: not valid JSON ({error}); {fix}") from None
    if not isinstance(data, dict):
        raise RunDirectoryError(f"{path}: holds {type(data).__name__}, not the run's settings; {fix}")
    fields = {field.name: field for field in dataclasses.fields(RunConfig)}
    missing = [name for name, field in fields.items() if name not in data and field.default is dataclasses.MISSING]
    if missing:
        raise RunDirectoryError(f"{path}: lacks the setting(s) {', '.join(missing)}; {fix}")
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise RunDirectoryError(
            f"{path}: unknown setting(s) {', '.join(unknown)} (from another smol-dsl version?); {fix}"
        )
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
            raise RunDirectoryError(f"{path}: {name} is {json.dumps(value)[:40]}, not {expected}; {fix}")
    try:
        task_spec(data["task"])
    except ValueError as error:  # "unknown task 'x'; the tasks are ..."
        raise RunDirectoryError(f"{path}: {error}; {fix}") from None
    for name in CONFIG_AT_LEAST_ONE:
        if name in data and data[name] < 1:
            raise RunDirectoryError(f"{path}: {name} is {data[name]}, but must be at least 1; {fix}")
    data["hidden_layer_sizes"] = tuple(data["hidden_layer_sizes"])
    try:
        config = RunConfig(**data)
    except (UserInputError, ValueError) as error:  # a seed outside 0 .. 2**32 - 1, say
        raise RunDirectoryError(
            f"{path}: {error}; rerun the run with settings the runner accepts, {_leave_out(path.parent)}"
        ) from None
    if config.generations < 1:
        raise RunDirectoryError(
            f"{path}: {config.evaluations} evaluations in batches of {config.batch_size} make no generation; {fix}"
        )
    if config.generations < config.num_phases:
        raise RunDirectoryError(
            f"{path}: {config.num_phases} phases but only {config.generations} generations; the runner refuses "
            f"such settings, so smol-dsl did not write this file; {fix}"
        )
    return config


def read_certificate(path: Path) -> tuple[str, float, dict[str, float]]:
    """The schedule's name, the start of its final-body tail and its final body (the channels
    whose final factor is not 1, by name), from certificate.json."""
    fix = f"rerun the run, {_leave_out(path.parent)}"
    try:
        data = json.loads(read_text(path))
    except (json.JSONDecodeError, RecursionError) as error:
        raise RunDirectoryError(f"{path}: not valid JSON ({error}); {fix}") from None
    name = data.get("name") if isinstance(data, dict) else None
    tail = data.get("tail_start") if isinstance(data, dict) else None
    if not isinstance(name, str) or not name:
        raise RunDirectoryError(f'{path}: no schedule name ("name"); {fix}')
    if not isinstance(tail, int | float) or isinstance(tail, bool) or not 0 <= tail <= 1:
        raise RunDirectoryError(
            f'{path}: "tail_start" must be a number from 0 to 1, not {json.dumps(tail)[:40]}; {fix}'
        )
    final = data.get("final_body", {})  # absent before multi-channel schedules: the standard body
    if not isinstance(final, dict) or not all(
        isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value) and value > 0
        for value in final.values()
    ):
        raise RunDirectoryError(f'{path}: "final_body" must map channels to factors above 0; {fix}')
    return name, float(tail), {str(channel): float(value) for channel, value in final.items() if value != 1}


def read_metrics(
    path: Path, config: RunConfig | None = None, schema: MetricsSchema = METRICS_SCHEMA
) -> list[dict[str, Any]]:
    """Every row of a run's metrics.csv, typed by `schema` and checked: all columns there,
    numbers where numbers belong, finite where they must be, each row once and in the
    runner's order (generation 0's init row, one train or reseed row per generation, a
    reevaluate row at each phase boundary), and, given the run's `config`, within its
    generations and phases. Raises RunDirectoryError naming the file and line."""
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
                raise RunDirectoryError(f"{path}: empty; the run wrote no metrics (it stopped at once); {rerun}")
            if schema is METRICS_SCHEMA:  # and a column per scheduled channel the header names
                schema = schema_of_header(header)
            missing = [name for name in schema.names if name not in header]
            if missing or len(set(header)) != len(header):
                what = f"lacks the column(s) {', '.join(missing)}" if missing else "names a column twice"
                raise RunDirectoryError(f"{path}:1: the header {what}; it should be {','.join(schema.names)}; {rerun}")
            for values in reader:
                line = reader.line_num
                if not values:
                    continue  # a blank line
                if len(values) != len(header):
                    raise RunDirectoryError(
                        f"{path}:{line}: {len(values)} values where the header has {len(header)} columns (a row "
                        f"cut short, or two rows run together); delete or repair the line, or {rerun}"
                    )
                try:
                    row = schema.parse_row(dict(zip(header, values, strict=True)))
                except ValueError as error:
                    raise RunDirectoryError(f"{path}:{line}: {error}; {rerun}") from None
                key = (row["event"], row["phase"], row["evaluations"])
                if key in seen:
                    raise RunDirectoryError(
                        f"{path}:{line}: repeats line {seen[key]} (event {row['event']}, phase {row['phase']}, "
                        f"{row['evaluations']} evaluations); every row must appear once: delete the repeated "
                        f"line, or {rerun}"
                    )
                seen[key] = line
                _check_order(path, line, row, rows[-1] if rows else None, lines[-1] if lines else 0, config, rerun)
                rows.append(row)
                lines.append(line)
    except UnicodeDecodeError:
        raise RunDirectoryError(f"{path}: not a text file (it is not UTF-8); {rerun}") from None
    except csv.Error as error:
        raise RunDirectoryError(f"{path}:{line + 1}: not readable as CSV ({error}); {rerun}") from None
    except OSError as error:
        raise RunDirectoryError(
            f"{path}: cannot be read ({error.strerror or error}); check its permissions, {_leave_out(directory)}"
        ) from None
    if not rows:
        raise RunDirectoryError(f"{path}: a header but no rows; the run wrote no metrics (it stopped at once); {rerun}")
    return rows


def _check_order(
    path: Path,
    line: int,
    row: dict[str, Any],
    previous: dict[str, Any] | None,
    previous_line: int,
    config: RunConfig | None,
    rerun: str,
) -> None:
    """A row follows the one before as the runner writes them."""
    where = f"{path}:{line}"
    if config is not None and row["generation"] > config.generations:
        raise RunDirectoryError(
            f"{where}: generation {row['generation']}, but {CONFIG_FILE} gives the run {config.generations} "
            f"generations; the two files are from different runs: {rerun}"
        )
    if config is not None and row["phase"] >= config.num_phases:
        raise RunDirectoryError(
            f"{where}: phase {row['phase']}, but {CONFIG_FILE} gives the run {config.num_phases} phases "
            f"(0 to {config.num_phases - 1}); the two files are from different runs: {rerun}"
        )
    if previous is None:
        if row["event"] != "init" or row["generation"] != 0:
            raise RunDirectoryError(
                f"{where}: the first row must be generation 0's init row, not generation {row['generation']}'s "
                f"{row['event']} row; the start of the file is missing: {rerun}"
            )
        return
    expected = previous["generation"] + (0 if row["event"] == "reevaluate" else 1)
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
    final_body: Mapping[str, float] = dataclasses.field(default_factory=dict)  # channels not ending at 1

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
        return alpha_one_evaluations(self.rows, first_tail_phase(self.tail_start, self.config.num_phases))

    def final_archive(self) -> FinalArchive:
        """The final archive, read (and checked) if it was not."""
        return self.archive if self.archive is not None else read_final_archive(self.directory, self.config)


def is_run_directory(path: Path) -> bool:
    """Whether path looks like a run directory, whole or not: it holds metrics.csv, or a
    config.json with another file the runner writes. `read_run` says what is wrong with it."""
    if (path / METRICS_FILE).is_file():
        return True
    return (path / CONFIG_FILE).is_file() and any((path / name).is_file() for name in RUN_MARKERS)


def read_run(directory: Path) -> RunRecord:
    """Read and check a run directory: config.json, certificate.json, schedule.sched, every
    row of metrics.csv and, if the run has finished, archive.npz. Raises RunDirectoryError
    naming the file (and line) that cannot be used, and what to do."""
    directory = Path(directory)
    config = read_config(directory / CONFIG_FILE)
    name, tail_start, final_body = read_certificate(directory / CERTIFICATE_FILE)
    source = read_text(directory / SCHEDULE_FILE)
    rows = read_metrics(directory / METRICS_FILE, config)
    run = RunRecord(directory, config, name, source, tail_start, rows, final_body=final_body)
    if run.finished:
        run = dataclasses.replace(run, archive=read_final_archive(directory, config))
    return run


def files_markdown(files: Sequence[tuple[str, str]] = FILES) -> str:
    """A table of files and what they hold, in Markdown (docs/runner.md holds FILES')."""
    lines = ["| file | contents |", "| --- | --- |"]
    lines += [f"| `{name}` | {contents} |" for name, contents in files]
    return "\n".join(lines) + "\n"
