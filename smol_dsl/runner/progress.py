"""The live progress bar of a run and its one-line summary."""

from __future__ import annotations

import math
import sys
import time
from typing import TYPE_CHECKING, Any

from smol_dsl.errors import counted
from smol_dsl.rundir import ALPHA, METRIC_FIELDS
from smol_dsl.rundir.metrics import BOUNDARY_EVENTS, DEVELOPMENT, REEVALUATION

if TYPE_CHECKING:
    from smol_dsl.language.schedule import Schedule
    from smol_dsl.rundir.config import RunConfig
    from smol_dsl.runner.training import RunResult


class ProgressBar:
    """A tqdm bar over generations. For one run it shows the phase, alpha and every other
    scheduled channel's factor, coverage, max fitness, what the phase's re-evaluation kept
    and evals/s; for a sweep (`update` given every run's row) the phase, the best max
    fitness and the median coverage over runs, the median share of cells the re-evaluation
    kept filled, and evals/s over all runs. A re-evaluation that left under half the cells
    filled is written above the bar (`reevaluation_warning`). The bar appears with the
    first row, so a run refused before it trains (a resume with other settings) prints none."""

    def __init__(self, config: RunConfig) -> None:
        self._bar: Any = None  # a tqdm bar, from the first row on
        self._config = config
        self._started = time.perf_counter()
        self._first_evaluations: int | None = None
        self._reevaluation = ""  # the current phase's re-evaluation, in a few words

    def update(self, rows: list[dict[str, Any]], total: int) -> None:
        """Show the latest row of every run (one, or every run of a sweep)."""
        if self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(total=self._config.generations + 1, unit="gen", dynamic_ncols=True, leave=True)
        evaluations = sum(row["evaluations"] + row["reevaluations"] for row in rows)
        if self._first_evaluations is None:
            self._first_evaluations = evaluations
            self._started = time.perf_counter()
        row = rows[0]
        if row["event"] in BOUNDARY_EVENTS:
            moved = any(r["event"] == REEVALUATION for r in rows)
            self._reevaluation = reevaluation_summary(rows) if moved else "body held"
            warning = reevaluation_warning(rows, self._config.num_phases)
            if warning is not None:
                self._bar.write(warning, file=sys.stderr)
        else:
            self._bar.n = row["generation"] + 1
        elapsed = max(time.perf_counter() - self._started, 1e-9)
        rate = (evaluations - self._first_evaluations) / elapsed
        phase = f"phase {row['phase']} of 0-{self._config.num_phases - 1}"
        if len(rows) == 1:
            body = " ".join(f"{name} {row[name]:.3f}" for name in (ALPHA, *channel_columns(row)))
            body += "".join(f" {name} {row[name]}" for name in row if name.startswith(DEVELOPMENT))
            about = f"{phase} {body} cov {row['coverage']:.1f}% max {row['max_fitness']:.1f}"
        else:
            coverage = sorted(r["coverage"] for r in rows)[len(rows) // 2]
            best = max(r["max_fitness"] for r in rows)
            about = f"{len(rows)} runs, {phase} best max {best:.1f} median cov {coverage:.1f}%"
        reevaluation = f" {self._reevaluation}" if self._reevaluation else ""
        self._bar.set_postfix_str(f"{about}{reevaluation} {rate:.0f} evals/s", refresh=False)
        self._bar.refresh()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


class ReevaluationWarnings:
    """A progress callback that shows nothing but `reevaluation_warning`s (on stderr): what
    a run without a progress bar still says."""

    def __init__(self, config: RunConfig) -> None:
        self._phases = config.num_phases

    def update(self, rows: list[dict[str, Any]], total: int) -> None:
        """Warn of a re-evaluation that left under half the cells filled."""
        warning = reevaluation_warning(rows, self._phases) if rows[0]["event"] in BOUNDARY_EVENTS else None
        if warning is not None:
            print(warning, file=sys.stderr, flush=True)


LOW_KEPT = 0.5
"""A re-evaluation that leaves fewer than this share of the cells filled is reported."""


def _measured(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows that count a re-evaluation of some elites."""
    return [row for row in rows if row.get("reevaluated")]


def reevaluation_summary(rows: list[dict[str, Any]]) -> str:
    """A re-evaluation in a few words: for one run what became of its elites, for several
    the median share of cells left filled."""
    measured = _measured(rows)
    if not measured:
        return ""
    if len(rows) == 1:
        row = measured[0]
        return (
            f"reeval {row['reevaluated']}: kept {row['kept']} moved {row['moved']} "
            f"collided {row['collided']} died {row['died']}"
        )
    shares = sorted((row["kept"] + row["moved"]) / row["reevaluated"] for row in measured)
    return f"reeval median {shares[len(shares) // 2]:.0%} of cells kept"


def reevaluation_warning(rows: list[dict[str, Any]], num_phases: int) -> str | None:
    """One line when a phase boundary's re-evaluation left under half of a run's cells
    filled (its elites' new descriptors fell into fewer cells, or they died), None
    otherwise."""
    low = [row for row in _measured(rows) if row["kept"] + row["moved"] < LOW_KEPT * row["reevaluated"]]
    if not low:
        return None
    phase = f"phase {low[0]['phase']} of 0-{num_phases - 1}"
    if len(rows) == 1:
        row = low[0]
        return (
            f"{phase}: re-evaluating the archive in the new body left {row['kept'] + row['moved']} of its "
            f"{row['reevaluated']} cells filled ({row['kept']} elites kept their cell, {row['moved']} moved, "
            f"{row['collided']} lost their new cell to a better elite, {row['died']} died): the new body "
            "sends elites to fewer cells; metrics.csv counts every re-evaluation"
        )
    worst = min(low, key=lambda row: (row["kept"] + row["moved"]) / row["reevaluated"])
    return (
        f"{phase}: re-evaluation left under half the cells filled in {len(low)} of {len(rows)} runs "
        f"(fewest: {worst['kept'] + worst['moved']} of {worst['reevaluated']}; {worst['collided']} collided, "
        f"{worst['died']} died); each run's metrics.csv counts them"
    )


def channel_columns(row: dict[str, Any]) -> list[str]:
    """A metrics row's columns of scheduled channels other than plain gear (`alpha`, which
    every row has)."""
    return [name for name in row if name not in METRIC_FIELDS and not name.startswith(DEVELOPMENT)]


def summary_line(result: RunResult, schedule: Schedule) -> str:
    final = result.final
    where = f" -> {result.out_dir}" if result.out_dir is not None else ""
    total = final["evaluations"] + final["reevaluations"]
    done = (
        f"done: {result.config.task} under {schedule.name}, seed {result.config.seed}: "
        f"max fitness {final['max_fitness']:.2f}, coverage {final['coverage']:.1f}%, "
        f"QD score {final['qd_score']:.1f}; {final['evaluations']} training + {final['reevaluations']} "
        f"re-evaluation evaluations in {format_duration(result.seconds)} "
        f"({total / max(result.seconds, 1e-9):.0f} evals/s){where}"
    )
    if result.out_dir is None:
        return done
    return f"{done}\nnext: smol-dsl render {result.out_dir} -o best.gif (the best elite's gait)"


def sweep_summary(results: list[RunResult], out_dir: Any) -> str:
    """What a finished sweep prints: its size, time and throughput, and what to do next."""
    seconds = max(result.seconds for result in results)
    total = sum(r.final["evaluations"] + r.final["reevaluations"] for r in results)
    return (
        f"done: {counted(len(results), 'run')} of {results[0].config.task} in {format_duration(seconds)} "
        f"({total / max(seconds, 1e-9):.0f} evals/s over all runs) -> {out_dir}\n"
        f"next: smol-dsl report {out_dir}"
    )


def format_duration(seconds: float) -> str:
    minutes, whole = divmod(math.ceil(seconds), 60)
    return f"{minutes}m{whole:02d}s" if minutes else f"{whole}s"
