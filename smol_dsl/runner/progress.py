"""The live progress bar of a run and its one-line summary."""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any

from smol_dsl.rundir import ALPHA, METRIC_FIELDS

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir.config import RunConfig
    from smol_dsl.runner.training import RunResult


class ProgressBar:
    """A tqdm bar over generations. For one run it shows the phase, alpha and every other
    scheduled channel's factor, coverage, max fitness and evals/s; for a sweep (`update`
    given every run's row) the phase, the best max fitness and the median coverage over
    runs, and evals/s over all runs."""

    def __init__(self, config: RunConfig) -> None:
        from tqdm import tqdm

        self._bar = tqdm(total=config.generations + 1, unit="gen", dynamic_ncols=True, leave=True)
        self._config = config
        self._started = time.perf_counter()
        self._first_evaluations: int | None = None

    def update(self, rows: dict[str, Any] | list[dict[str, Any]], total: int) -> None:
        """Show the latest row of a run, or the latest rows of every run of a sweep."""
        rows = [rows] if isinstance(rows, dict) else rows
        evaluations = sum(row["evaluations"] + row["reevaluations"] for row in rows)
        if self._first_evaluations is None:
            self._first_evaluations = evaluations
            self._started = time.perf_counter()
        row = rows[0]
        if row["event"] != "reevaluate":
            self._bar.n = row["generation"] + 1
        elapsed = max(time.perf_counter() - self._started, 1e-9)
        rate = (evaluations - self._first_evaluations) / elapsed
        phase = f"phase {row['phase'] + 1}/{self._config.num_phases}"
        if len(rows) == 1:
            body = " ".join(f"{name} {row[name]:.3f}" for name in (ALPHA, *channel_columns(row)))
            about = f"{phase} {body} cov {row['coverage']:.1f}% max {row['max_fitness']:.1f}"
        else:
            coverage = sorted(r["coverage"] for r in rows)[len(rows) // 2]
            best = max(r["max_fitness"] for r in rows)
            about = f"{len(rows)} runs, {phase} best max {best:.1f} median cov {coverage:.1f}%"
        self._bar.set_postfix_str(f"{about} {rate:.0f} evals/s", refresh=False)
        self._bar.refresh()

    def close(self) -> None:
        self._bar.close()


def channel_columns(row: dict[str, Any]) -> list[str]:
    """A metrics row's columns of scheduled channels other than plain gear (`alpha`, which
    every row has)."""
    return [name for name in row if name not in METRIC_FIELDS]


def summary_line(result: RunResult, schedule: Schedule) -> str:
    final = result.final
    where = f" -> {result.out_dir}" if result.out_dir is not None else ""
    total = final["evaluations"] + final["reevaluations"]
    return (
        f"done: {result.config.task} under {schedule.name}, seed {result.config.seed}: "
        f"max fitness {final['max_fitness']:.2f}, coverage {final['coverage']:.1f}%, "
        f"QD score {final['qd_score']:.1f}; {final['evaluations']} training + {final['reevaluations']} "
        f"re-evaluation evaluations in {format_duration(result.seconds)} "
        f"({total / max(result.seconds, 1e-9):.0f} evals/s){where}"
    )


def sweep_summary(results: list[RunResult], out_dir: Any) -> str:
    """What a finished sweep prints: its size, time and throughput, and what to do next."""
    seconds = max(result.seconds for result in results)
    total = sum(r.final["evaluations"] + r.final["reevaluations"] for r in results)
    return (
        f"done: {len(results)} runs of {results[0].config.task} in {format_duration(seconds)} "
        f"({total / max(seconds, 1e-9):.0f} evals/s over all runs) -> {out_dir}\n"
        f"next: smol-dsl report {out_dir}"
    )


def format_duration(seconds: float) -> str:
    minutes, whole = divmod(math.ceil(seconds), 60)
    return f"{minutes}m{whole:02d}s" if minutes else f"{whole}s"
