"""A run directory as a whole: set up with its settings, schedule and certificate
(`write_run_files`), and read back, every file checked (`read_run` -> `RunRecord`)."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from smol_dsl.errors import ScheduleError
from smol_dsl.language.channels import GEAR, Channel
from smol_dsl.rundir.archive import FinalArchive, read_final_archive
from smol_dsl.rundir.certificate import (
    SOURCE_DIGEST,
    CertificateRecord,
    certificate_record,
    certificate_text,
    read_certificate,
    source_digest,
)
from smol_dsl.rundir.config import RunConfig, read_config
from smol_dsl.rundir.environment import environment_text, read_environment, read_environment_changes
from smol_dsl.rundir.files import read_text, write_text
from smol_dsl.rundir.layout import (
    CERTIFICATE_FILE,
    CERTIFICATE_TEXT_FILE,
    CONFIG_FILE,
    ENVIRONMENT_FILE,
    METRICS_FILE,
    SCHEDULE_FILE,
    RunDirectoryError,
    leave_out,
)
from smol_dsl.rundir.metrics import (
    BOUNDARY_EVENTS,
    DEVELOPMENT,
    column_name,
    schedule_schema,
    scheduled_columns,
    trained_bodies,
)
from smol_dsl.rundir.metrics_reader import final_body_evaluations, first_tail_phase, read_metrics
from smol_dsl.tasks import task_spec
from smol_dsl.tasks.anatomy import resolve

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule


def write_run_files(
    directory: Path, config: RunConfig, schedule: Schedule, environment: dict[str, Any] | None = None
) -> list[Path]:
    """A new run's config.json, environment.json (`describe_environment`; None: left out),
    schedule.sched, certificate.json and certificate.txt, each written atomically. If one
    cannot be written (a full disk), those written are removed and the OSError, naming the
    file, is raised: nothing is left half set up."""
    texts = {
        CONFIG_FILE: config.to_json(),
        **({ENVIRONMENT_FILE: environment_text(environment)} if environment is not None else {}),
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
    channels: tuple[Channel, ...] = (GEAR,)  # the schedule's channels, in declared order
    body: Mapping[str, tuple[float, ...]] = dataclasses.field(default_factory=dict)
    """The final body resolved per part (`tasks.anatomy.resolve`): each actuator's gear and
    link's mass factor, friction's and gravity's; a kind left out is 1 throughout."""
    environment: Mapping[str, Any] | None = None
    """What the run was started under (environment.json; None where the run recorded none,
    empty where it was resumed without one and its start is unknown)."""
    environment_changes: tuple[Mapping[str, Any], ...] = ()
    """The environments it was resumed under since (each with its `differences`)."""

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

    @property
    def paced(self) -> bool:
        """Whether the run's schedule waits for its archive (its rows log a development step)."""
        return any(name.startswith(DEVELOPMENT) for name in self.rows[0])

    @property
    def body_columns(self) -> tuple[str, ...]:
        """metrics.csv's columns of the run's scheduled channels (`alpha` for plain gear)."""
        return scheduled_columns(self.channels)

    def phase_column(self, column: str) -> np.ndarray:
        """(phases,): one body column's value in every phase as the run trained (1 for a
        channel it does not schedule)."""
        names = [column_name(channel) for channel in self.channels]
        if column not in names:
            return np.ones(self.config.num_phases, dtype=np.float32)
        return self.phase_bodies()[:, names.index(column)]

    @property
    def body_changes(self) -> int:
        """The phase boundaries at which the run was re-evaluated in a new body (a paced run
        held its body at the others)."""
        return sum(row["event"] == "reevaluate" for row in self.rows)

    def coverage_before_tail(self) -> float | None:
        """Coverage (%) at the end of the last phase before the first one wholly in the
        final-body tail: what the curve left the archive with before its last change of body
        (None for a run all in its tail, or one that has not got there)."""
        tail = first_tail_phase(self.tail_start, self.config.num_phases)
        before = [row for row in self.rows if row["phase"] == tail - 1 and row["event"] not in BOUNDARY_EVENTS]
        return before[-1]["coverage"] if tail > 0 and before and any(r["phase"] >= tail for r in self.rows) else None

    def curve(self, metric: str) -> tuple[np.ndarray, np.ndarray]:
        """Training evaluations and the metric, one point per logged row."""
        evaluations = np.asarray([row["evaluations"] for row in self.rows], dtype=float)
        return evaluations, np.asarray([row[metric] for row in self.rows], dtype=float)

    def final_body_evaluations(self) -> float | None:
        """Training evaluations when the body becomes the final one for good (the first tail
        phase starts; for plain gear, where alpha is 1 for good)."""
        return final_body_evaluations(self.rows, first_tail_phase(self.tail_start, self.config.num_phases))

    def phase_bodies(self) -> np.ndarray:
        """The body of every phase as the run trained in it, (phases, channels) in the order
        of `channels`: the schedule's certified values under the run's seed (float32); a
        paced run's, those its clocks reached, as its metrics rows log them."""
        from smol_dsl.seeds import schedule_key

        schedule = _parsed(self.schedule_source)
        if isinstance(schedule, ScheduleError):
            raise RunDirectoryError(f"{self.directory / SCHEDULE_FILE}: {schedule}")
        values = schedule.checked_phase_values(self.config.num_phases, schedule_key(self.seed), schedule.channels)
        if schedule.is_paced:
            return trained_bodies(values, schedule.channels, self.rows)
        return np.asarray(values, dtype=np.float32)

    def last_phase_body(self) -> dict[Channel, float]:
        """The body the run ended on: its last phase's factor per channel (`phase_bodies`); `final_body`
        holds only the declared `final` factors."""
        return dict(zip(self.channels, self.phase_bodies()[-1].tolist(), strict=True))

    def final_archive(self) -> FinalArchive:
        """The final archive, read (and checked) if it was not."""
        return self.archive if self.archive is not None else read_final_archive(self.directory, self.config)


def read_run(directory: Path) -> RunRecord:
    """Read and check a run directory: config.json, certificate.json, schedule.sched, every
    row of metrics.csv and, if the run has finished, archive.npz. What can be derived is
    derived, not believed: the schedule is parsed and verified again from schedule.sched (its
    channels, where its tail starts and its final body, resolved per actuator and link of the
    config's task), certificate.json must agree with it, and metrics.csv must hold exactly
    its channels' columns. Raises RunDirectoryError naming the file (and line) that cannot be
    used, and what to do."""
    directory = Path(directory)
    config = read_config(directory / CONFIG_FILE)
    certificate = read_certificate(directory / CERTIFICATE_FILE)
    source = read_text(directory / SCHEDULE_FILE)
    _check_source(directory, certificate, source)
    schedule = _schedule_of(directory, source, config)
    final_body = {channel.name: value for channel, value in schedule.final_body.items() if value != 1}
    _check_certificate(directory, certificate, schedule, final_body)
    rows = read_metrics(directory / METRICS_FILE, config, schedule_schema(schedule))
    _check_tail_rows(directory, rows, schedule, config.num_phases)
    run = RunRecord(
        directory,
        config,
        certificate.name,
        source,
        float(schedule.tail_start),
        rows,
        final_body=final_body,
        channels=schedule.channels,
        body=resolve(task_spec(config.task).anatomy, schedule.final_body),
        environment=read_environment(directory),
        environment_changes=tuple(read_environment_changes(directory)),
    )
    if run.finished:
        run = dataclasses.replace(run, archive=read_final_archive(directory, config))
        _check_final_scores(run)
    return run


def _check_final_scores(run: RunRecord) -> None:
    """metrics.csv's last row gives the scores of archive.npz's elites under the config's
    task, as QDax computes them: coverage, max fitness and QD score (whose offset per cell is
    the task's, so that a run relabelled as another task with the same network is caught)."""
    archive, config = run.final_archive(), run.config
    filled = np.asarray(archive.filled, dtype=bool)
    fitnesses = np.asarray(archive.fitnesses, dtype=np.float64)[filled]
    offset = task_spec(config.task).reward_offset * config.episode_length
    derived = {
        "coverage": (100.0 * filled.mean(), 100.0),
        "max_fitness": (fitnesses.max() if filled.any() else -math.inf, max(1.0, np.abs(fitnesses).max(initial=0))),
        "qd_score": (
            fitnesses.sum() + offset * filled.sum(),
            max(1.0, np.abs(fitnesses).sum() + offset * filled.sum()),
        ),
    }
    for name, (value, scale) in derived.items():
        logged = float(run.final[name])
        if logged == value or abs(logged - value) <= FINAL_SCORE_TOLERANCE * scale:
            continue
        raise RunDirectoryError(
            f"{run.directory / METRICS_FILE}: its last row's {name} ({logged:.6g}) is not what the elites of "
            f"archive.npz score under {CONFIG_FILE}'s task {config.task} ({value:.6g}); the files are from different "
            f"runs, or one was edited: rerun the run, {leave_out(run.directory)}"
        )


FINAL_SCORE_TOLERANCE = 1e-5
"""How far (relative to the scores' magnitude) metrics.csv's float32 scores may lie from the
archive's, summed here in float64."""


@functools.lru_cache(maxsize=64)
def _parsed(source: str) -> Schedule | ScheduleError:
    """A schedule.sched text parsed and verified (once per text: a sweep's runs share one).
    The language (sympy, Lark) is imported here, so that reading a run's other files does not."""
    from smol_dsl.language.schedule import parse

    try:
        return parse(source)
    except ScheduleError as error:
        return error


def _schedule_of(directory: Path, source: str, config: RunConfig) -> Schedule:
    """The run's schedule, from its schedule.sched, checked against the config's task."""
    path = directory / SCHEDULE_FILE
    fix = f"it is not the file the run was set up with: rerun the run, {leave_out(directory)}"
    parsed = _parsed(source)
    if isinstance(parsed, ScheduleError):
        first = str(parsed.located(source, str(path))).splitlines()[0]
        raise RunDirectoryError(f"{first}; {fix}")
    try:
        task_spec(config.task).check_schedule(parsed, config.physics)
    except ScheduleError as error:
        first = str(error.located(source, str(path))).splitlines()[0]
        raise RunDirectoryError(
            f"{first} (the task of {CONFIG_FILE}); the two files are from different runs: {fix}"
        ) from None
    return parsed


def _check_source(directory: Path, certificate: CertificateRecord, source: str) -> None:
    """schedule.sched is the text certificate.json proves (its SHA-256); a run set up before
    the digest was recorded is checked by what its certificate says instead."""
    if certificate.source_digest is not None and certificate.source_digest != source_digest(source):
        raise RunDirectoryError(
            f"{directory / SCHEDULE_FILE}: it is not the text the run was trained on ({CERTIFICATE_FILE}'s "
            f"{SOURCE_DIGEST} differs): it was edited after the run was set up. Restore it, rerun the run, or "
            f"{leave_out(directory)}"
        )


def _check_tail_rows(directory: Path, rows: list[dict[str, Any]], schedule: Schedule, num_phases: int) -> None:
    """metrics.csv's rows in the final-body tail log the schedule's final body (each channel's
    column its final factor, to float32 rounding): a log of another schedule is caught
    without recomputing its phases."""
    first_tail = first_tail_phase(float(schedule.tail_start), num_phases)
    for channel, final in schedule.final_body.items():
        column = column_name(channel)
        for number, row in enumerate(rows, start=2):
            if row["phase"] < first_tail or math.isclose(row[column], final, rel_tol=1e-6):
                continue
            raise RunDirectoryError(
                f"{directory / METRICS_FILE}:{number}: {column} is {row[column]:g} in phase {row['phase']}, where "
                f"{SCHEDULE_FILE} is at its final body ({column} {final:g}); the files are from different runs, or "
                f"one was edited: rerun the run, {leave_out(directory)}"
            )


def _check_certificate(
    directory: Path, certificate: CertificateRecord, schedule: Schedule, final_body: Mapping[str, float]
) -> None:
    """certificate.json says what verifying schedule.sched again proves: the same channels,
    the same final body (its factors other than 1), the same start of the tail."""
    found = {
        "channels": (certificate.channels, schedule.channels),
        "final_body": (certificate.final_body, final_body),
        "tail_start": (certificate.tail_start, float(schedule.tail_start)),
    }
    for name, (said, proven) in found.items():
        same = math.isclose(said, proven, rel_tol=1e-12, abs_tol=1e-15) if name == "tail_start" else said == proven
        if same:
            continue
        raise RunDirectoryError(
            f"{directory / CERTIFICATE_FILE}: its {name!r} ({_shown(said)}) is not what {SCHEDULE_FILE} proves "
            f"({_shown(proven)}); one of the two files was edited or comes from another run: rerun the run, "
            f"{leave_out(directory)}"
        )


def _shown(value: object) -> str:
    """A certificate field for a message: channels by name, an empty body as `none`."""
    if isinstance(value, tuple):
        return ", ".join(str(item) for item in value)
    if isinstance(value, dict):
        return ", ".join(f"{name} {factor:g}" for name, factor in value.items()) or "none (every factor 1)"
    return f"{value:g}" if isinstance(value, float) else str(value)
