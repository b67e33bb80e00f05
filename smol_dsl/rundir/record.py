"""A run directory as a whole: set up with its settings, schedule and certificate
(`write_run_files`), and read back, every file checked (`read_run` -> `RunRecord`)."""

from __future__ import annotations

import contextlib
import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from smol_dsl.language.channels import GEAR, Channel
from smol_dsl.rundir.archive import FinalArchive, read_final_archive
from smol_dsl.rundir.certificate import certificate_record, certificate_text, read_certificate
from smol_dsl.rundir.config import RunConfig, read_config
from smol_dsl.rundir.files import read_text, write_text
from smol_dsl.rundir.layout import CERTIFICATE_FILE, CERTIFICATE_TEXT_FILE, CONFIG_FILE, METRICS_FILE, SCHEDULE_FILE
from smol_dsl.rundir.metrics import final_body_evaluations, first_tail_phase, read_metrics

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule


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

    def final_body_evaluations(self) -> float | None:
        """Training evaluations when the body becomes the final one for good (the first tail
        phase starts; for plain gear, where alpha is 1 for good)."""
        return final_body_evaluations(self.rows, first_tail_phase(self.tail_start, self.config.num_phases))

    def final_archive(self) -> FinalArchive:
        """The final archive, read (and checked) if it was not."""
        return self.archive if self.archive is not None else read_final_archive(self.directory, self.config)


def read_run(directory: Path) -> RunRecord:
    """Read and check a run directory: config.json, certificate.json, schedule.sched, every
    row of metrics.csv and, if the run has finished, archive.npz. Raises RunDirectoryError
    naming the file (and line) that cannot be used, and what to do."""
    directory = Path(directory)
    config = read_config(directory / CONFIG_FILE)
    certificate = read_certificate(directory / CERTIFICATE_FILE)
    source = read_text(directory / SCHEDULE_FILE)
    rows = read_metrics(directory / METRICS_FILE, config)
    run = RunRecord(
        directory,
        config,
        certificate.name,
        source,
        certificate.tail_start,
        rows,
        final_body=certificate.final_body,
        channels=certificate.channels,
    )
    if run.finished:
        run = dataclasses.replace(run, archive=read_final_archive(directory, config))
    return run
