"""`smol-dsl robustness`'s measurements as the results read them: robustness.csv's rows per
schedule and seed (`Robustness`), checked against the runs a report shows
(`robustness_for_report`), and the command itself (`measure_and_write`): the output, the
runs and the perturbations checked before anything is measured, then the files written
together. The tables are `results.robustness_tables`'s, the figure
`results.robustness_figure`'s. Nothing here imports JAX; measuring does.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from smol_dsl.errors import counted
from smol_dsl.results.output import check_writable_directory, write_files
from smol_dsl.results.runs import MOST_PROBLEMS, ReportError, find_run_directories, load_runs
from smol_dsl.rundir import (
    MEDIAN,
    METRICS_FILE,
    ROBUSTNESS_FILE,
    RobustnessRow,
    RunDirectoryError,
    read_robustness,
    read_run,
)
from smol_dsl.rundir.robustness import robustness_csv

if TYPE_CHECKING:
    from smol_dsl.rescoring.perturbations import Perturbations
    from smol_dsl.rundir import RunRecord

ROBUSTNESS_FILES = ("robustness.csv", "robustness.md", "robustness.tex", "robustness.png", "robustness.pdf")
"""What `smol-dsl robustness` writes (robustness.csv is `smol_dsl.rundir`'s ROBUSTNESS_FILE)."""


@dataclass(frozen=True)
class Robustness:
    """robustness.csv's rows (a whole grid: `read_robustness`) with the order of the
    schedules (the report's)."""

    task: str
    rows: list[RobustnessRow]
    schedules: list[str]

    @property
    def perturbations(self) -> list[str]:
        return list(dict.fromkeys(row.perturbation for row in self.rows))

    @property
    def channels(self) -> dict[str, list[str]]:
        """Each perturbed body channel's families (perturbations), in order."""
        from smol_dsl.rescoring.perturbations import channel_of

        channels: dict[str, list[str]] = {}
        for perturbation in self.perturbations:
            channel = channel_of(perturbation)
            if channel is not None:
                channels.setdefault(channel, []).append(perturbation)
        return channels

    def per_seed(self, perturbation: str, sample: str, value: str) -> dict[str, dict[int, float]]:
        """Each schedule's `value` (a RobustnessRow field or share) of one sample, by seed."""
        scores: dict[str, dict[int, float]] = {name: {} for name in self.schedules}
        for row in self.rows:
            if row.perturbation == perturbation and row.sample == sample:
                scores[row.schedule][row.seed] = float(getattr(row, value))
        return scores

    def per_run(self, perturbation: str, sample: str, value: str) -> dict[str, np.ndarray]:
        """Each schedule's `value` of one sample, one per seed, in the order of the seeds."""
        return {
            name: np.asarray([runs[seed] for seed in sorted(runs)], dtype=float)
            for name, runs in self.per_seed(perturbation, sample, value).items()
        }

    def mean_over_samples(self, perturbation: str, value: str = "kept_share") -> dict[str, dict[int, float]]:
        """Each schedule's `value` (the share of elites kept in their cell), each run's mean over
        the perturbation's samples, by seed."""
        samples = [self.per_seed(perturbation, row.sample, value) for row in self.samples(perturbation)]
        return {
            name: {seed: float(np.mean([sample[name][seed] for sample in samples])) for seed in samples[0][name]}
            for name in self.schedules
        }

    def robust_coverage(self, directory: str | Path, perturbation: str) -> float:
        """A run's robust coverage under a perturbation (its corrected archive's coverage)."""
        resolved = Path(directory).resolve()
        return next(
            row.coverage
            for row in self.rows
            if Path(row.directory).resolve() == resolved and row.perturbation == perturbation and row.sample == MEDIAN
        )

    def samples(self, perturbation: str) -> list[RobustnessRow]:
        """The first run's rows of a perturbation's samples (its labels and factors), in order."""
        first = self.rows[0].directory
        return [
            row
            for row in self.rows
            if row.directory == first and row.perturbation == perturbation and row.sample != MEDIAN
        ]

    def channel_samples(self, channel: str) -> list[RobustnessRow]:
        """The first run's rows of every sample of a channel's body families, by factor."""
        rows = [row for perturbation in self.channels[channel] for row in self.samples(perturbation)]
        return sorted(rows, key=lambda row: row.factor)


def robustness_of(rows: Sequence[RobustnessRow], task: str, order: Sequence[str] = ()) -> Robustness:
    """The rows, their schedules in `order` first (the report's), then as they come."""
    names = list(
        dict.fromkeys([name for name in order if any(r.schedule == name for r in rows)] + [r.schedule for r in rows])
    )
    return Robustness(task, list(rows), names)


def robustness_files(robustness: Robustness, relative_to: Path) -> dict[str, bytes]:
    """Every file `smol-dsl robustness` writes, by name, in memory: robustness.csv (run
    directories relative to `relative_to` where below it), .md, .tex, and the figure as PNG
    and PDF."""
    from smol_dsl.results.robustness_tables import robustness_markdown

    return {
        ROBUSTNESS_FILE: robustness_csv(robustness.rows, relative_to).encode(),
        "robustness.md": robustness_markdown(robustness).encode(),
        **robustness_figure_and_tables(robustness),
    }


def robustness_figure_and_tables(robustness: Robustness) -> dict[str, bytes]:
    """robustness.tex (the tests' tables) and the figure as PNG and PDF, by name."""
    from smol_dsl.results.robustness_figure import robustness_images
    from smol_dsl.results.robustness_tables import robustness_latex

    return {"robustness.tex": robustness_latex(robustness).encode(), **robustness_images(robustness)}


def robustness_for_report(paths: Sequence[Path], groups: Mapping[str, Sequence[RunRecord]], task: str) -> Robustness:
    """The robustness.csv files at `paths` (each a whole grid: `read_robustness`), checked
    against the report's runs (`groups`: each schedule's runs): every run has its rows, in
    one file only, and every row is of a run reported on. A ReportError says what does not
    match and how to measure again."""
    rows: list[RobustnessRow] = []
    source: dict[str, Path] = {}
    for path in paths:
        if not Path(path).is_file():
            raise ReportError(f"{path}: no such file; measure with `smol-dsl robustness DIR...` first")
        read = read_robustness(Path(path))
        for directory in dict.fromkeys(row.directory for row in read):
            if directory in source:
                raise ReportError(f"{directory} is measured in both {source[directory]} and {path}; keep one")
            source[directory] = Path(path)
        rows += read
    reported = [str(Path(run.directory).resolve()) for runs in groups.values() for run in runs]
    again = "measure the runs you report on again with `smol-dsl robustness DIR... --force`, or give --no-robustness"
    missing = [directory for directory in reported if directory not in source]
    if missing:
        more = f" (nor of {len(missing) - 1} more run(s))" if len(missing) > 1 else ""
        raise ReportError(f"{', '.join(str(p) for p in paths)} has no measurements of {missing[0]}{more}: {again}")
    foreign = [directory for directory in source if directory not in set(reported)]
    if foreign:
        more = f" (and {counted(len(foreign) - 1, 'other')})" if len(foreign) > 1 else ""
        raise ReportError(
            f"{source[foreign[0]]} measures {foreign[0]}{more}, which is not among the runs reported on: report on "
            f"every run it measures, or {again}"
        )
    return robustness_of(by_condition(rows, groups), task, list(groups))


def by_condition(rows: Sequence[RobustnessRow], groups: Mapping[str, Sequence[RunRecord]]) -> list[RobustnessRow]:
    """The rows with each run's `schedule` the name of its group among `groups` (the
    report's conditions: `SMOL on mjx` where the runs span several physics), found by its
    directory."""
    condition = {str(Path(run.directory).resolve()): name for name, runs in groups.items() for run in runs}
    return [dataclasses.replace(row, schedule=condition[str(Path(row.directory).resolve())]) for row in rows]


@dataclass(frozen=True)
class RobustnessReport:
    """What `measure_and_write` measured and wrote, and the unfinished runs it left out."""

    robustness: Robustness
    files: list[Path]
    left_out: list[str] = field(default_factory=list)


def check_robustness_output(out_dir: str | Path, force: bool = False) -> list[str]:
    """Refuse (ReportError) an output directory that is a file, cannot be made or written
    (tried: made, written and removed again), or holds earlier robustness files (unless
    `force`); returns those files."""
    out = check_writable_directory(out_dir, ROBUSTNESS_FILES, "smol-dsl robustness")
    _try_writing(out)
    earlier = [name for name in ROBUSTNESS_FILES if (out / name).is_file()]
    if earlier and not force:
        raise ReportError(
            f"{out} already holds robustness measurements ({', '.join(earlier)}); give --force to replace them "
            "(force=True in Python), or another output directory with -o"
        )
    return earlier


def _try_writing(out: Path) -> None:
    """Make `out` (and the directories above it that are missing), write a file into it and
    remove them all again: what permissions alone do not say (root, /proc, a read-only mount)."""
    missing = []
    existing = out
    while not existing.exists():
        missing.append(existing)
        existing = existing.parent
    made: list[Path] = []
    try:
        for directory in reversed(missing):
            directory.mkdir()
            made.append(directory)
        handle, name = tempfile.mkstemp(dir=out, prefix=".smol-dsl-robustness-", suffix=".tmp")
        os.close(handle)
        os.unlink(name)
    except OSError as error:
        what = "create" if len(made) < len(missing) else "write into"
        raise ReportError(f"cannot {what} {out} ({error.strerror or error}); give another -o") from None
    finally:
        for directory in reversed(made):
            directory.rmdir()


def runs_to_measure(
    paths: Sequence[str | Path], finished_only: bool = False, allow_mixed_environments: bool = False
) -> tuple[dict[str, list[RunRecord]], list[str]]:
    """The runs below `paths`, grouped as `report` groups them (`load_runs`), and the unfinished
    ones left out (each with why). A run that has not started or not finished is refused
    (RobustnessError, naming it) unless `finished_only`: then the finished ones are measured."""
    from smol_dsl.rescoring.perturbations import RobustnessError

    try:
        return load_runs(paths, allow_mixed_environments), []
    except ReportError:
        unfinished = unfinished_runs(paths)
        if not unfinished:
            raise
    directories = find_run_directories(paths)
    named = [f"{directory} {why}" for directory, why in unfinished.items()]
    more = len(named) - MOST_PROBLEMS
    shown = "; ".join(named[:MOST_PROBLEMS]) + (f"; and {more} more" if more > 0 else "")
    finished = [directory for directory in directories if directory not in unfinished]
    if not finished_only or not finished:
        offer = (
            f"measure the {counted(len(finished), 'finished run')} with --finished-only (finished_only=True in Python)"
            if finished
            else "none has finished"
        )
        raise RobustnessError(
            f"{len(unfinished)} of the {counted(len(directories), 'run')} in {', '.join(str(p) for p in paths)} "
            f"{'has' if len(unfinished) == 1 else 'have'} not finished: {shown}; finish "
            f"{'it' if len(unfinished) == 1 else 'them'} (`smol-dsl sweep ... --resume`), or {offer}"
        )
    return load_runs(finished, allow_mixed_environments), named


def unfinished_runs(paths: Sequence[str | Path]) -> dict[Path, str]:
    """The run directories below `paths` that have not started (no metrics.csv) or not
    finished (metrics.csv short of the last generation), each with why in words."""
    unfinished = {}
    for directory in find_run_directories(paths):
        if not (directory / METRICS_FILE).is_file():
            unfinished[directory] = f"has not started (no {METRICS_FILE})"
            continue
        try:
            run = read_run(directory)
        except RunDirectoryError:
            continue  # damaged, not unfinished: `load_runs` says what is wrong with it
        if not run.finished:
            generation = run.final["generation"]
            unfinished[directory] = f"has not finished (generation {generation} of {run.config.generations})"
    return unfinished


def measure_and_write(
    paths: Sequence[str | Path],
    out_dir: str | Path,
    perturbations: Perturbations | None = None,
    *,
    force: bool = False,
    allow_mixed_environments: bool = False,
    finished_only: bool = False,
    progress: Callable[[str], None] | None = None,
) -> RobustnessReport:
    """Re-score the final archives of the finished runs below `paths` under `perturbations`
    (`smol_dsl.rescoring.robustness`) and write robustness.csv, .md, .tex, .png and .pdf into
    `out_dir`, together and atomically. Everything is checked before anything is measured
    (the output directory, tried; the perturbations; the runs as `report` checks them, the
    unfinished ones refused or, with `finished_only`, left out; what measuring would hold),
    and measured before anything is written. `progress` is told the cost first
    (`perturbations.estimate`), then each sample."""
    from smol_dsl.rescoring.perturbations import DEFAULT_PERTURBATIONS, check_families, check_perturbations, estimate
    from smol_dsl.rescoring.robustness import measure_robustness

    perturbations = perturbations if perturbations is not None else DEFAULT_PERTURBATIONS
    check_robustness_output(out_dir, force)
    check_families(perturbations)
    groups, left_out = runs_to_measure(paths, finished_only, allow_mixed_environments)
    runs = [run for group in groups.values() for run in group]
    check_perturbations(runs, perturbations)
    if progress is not None:
        for run in left_out:
            progress(f"left out: {run}")
        progress(f"measuring {estimate(runs, perturbations)}")
    rows = by_condition(measure_robustness(runs, perturbations, progress=progress), groups)
    robustness = robustness_of(rows, runs[0].task, list(groups))
    files = robustness_files(robustness, Path(out_dir))
    return RobustnessReport(robustness, write_files(out_dir, files), left_out)
