"""The live progress bar of a run and its one-line summary."""

from __future__ import annotations

import time
from typing import Any

from smol_dsl.runner.config import RunConfig
from smol_dsl.runner.run import RunResult, format_duration
from smol_dsl.schedule import Schedule


class ProgressBar:
    """A tqdm bar over generations showing phase, alpha, coverage, max fitness, evals/s."""

    def __init__(self, config: RunConfig) -> None:
        from tqdm import tqdm

        self._bar = tqdm(total=config.generations + 1, unit="gen", dynamic_ncols=True, leave=True)
        self._config = config
        self._started = time.perf_counter()
        self._first_evaluations: int | None = None

    def update(self, row: dict[str, Any], total: int) -> None:
        evaluations = row["evaluations"] + row["reevaluations"]
        if self._first_evaluations is None:
            self._first_evaluations = evaluations
            self._started = time.perf_counter()
        if row["event"] != "reevaluate":
            self._bar.n = row["generation"] + 1
        elapsed = max(time.perf_counter() - self._started, 1e-9)
        rate = (evaluations - self._first_evaluations) / elapsed
        self._bar.set_postfix_str(
            f"phase {row['phase'] + 1}/{self._config.num_phases} alpha {row['alpha']:.3f} "
            f"cov {row['coverage']:.1f}% max {row['max_fitness']:.1f} {rate:.0f} evals/s",
            refresh=False,
        )
        self._bar.refresh()

    def close(self) -> None:
        self._bar.close()


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
