"""What `smol-dsl robustness` perturbs, and the checks that refuse what cannot be measured
before anything is: `Perturbations` (bodies per channel, other episode starts, the float
path), their names as robustness.csv's `perturbation` column writes them, and
`check_perturbations`. Imports no JAX."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from smol_dsl.errors import UserInputError, counted
from smol_dsl.tasks import task_spec

if TYPE_CHECKING:
    from smol_dsl.language.channels import Channel
    from smol_dsl.rundir import RunRecord

DEFAULT_FACTORS = (0.9, 0.95, 0.99, 0.9944, 1.0056, 1.01, 1.05, 1.1)
"""Body factors around the final body: the paper's SMOL step from one phase to the next
(alpha 1.5 to 1 over 90 phases: 0.56%) each way, and changes of 1, 5 and 10%."""
DEFAULT_STARTS = 8
BODY = "body"
FLOAT_PATH = "float path"
STARTS = "starts"


class RobustnessError(UserInputError):
    """Runs or perturbations that `smol-dsl robustness` cannot measure."""


@dataclass(frozen=True)
class Perturbations:
    """What to re-score every final archive under: `bodies`, (channel name, factors) pairs,
    each factor multiplying that channel's final factor; `starts` other episode starts (0:
    none); `float_path`, the same body in another program."""

    bodies: tuple[tuple[str, tuple[float, ...]], ...] = (("gear", DEFAULT_FACTORS),)
    starts: int = DEFAULT_STARTS
    float_path: bool = True

    @property
    def names(self) -> list[str]:
        """The perturbations, as robustness.csv's `perturbation` column names them."""
        return (
            [f"{BODY} {channel}" for channel, _ in self.bodies]
            + ([FLOAT_PATH] if self.float_path else [])
            + ([STARTS] if self.starts else [])
        )


def check_perturbations(runs: Sequence[RunRecord], perturbations: Perturbations) -> None:
    """A RobustnessError for what cannot be measured, before anything is: no runs, a run that
    has not finished, nothing to measure, a start count below 0, a body factor that is not
    finite and above 0 or given twice, a channel a run's schedule lacks, and a perturbed
    body outside what the task's physics takes (`smol-dsl check --task`'s ranges)."""
    from smol_dsl.language.channels import Channel

    if not runs:
        raise RobustnessError("no runs to measure; give run or sweep directories of finished runs")
    unfinished = [run for run in runs if not run.finished or run.archive is None]
    if unfinished:
        raise RobustnessError(
            f"{unfinished[0].directory} has not finished: it has no final archive to re-score"
            + (f" (nor have {counted(len(unfinished) - 1, 'other run')})" if len(unfinished) > 1 else "")
            + "; finish it with `--resume`, or leave it out"
        )
    if isinstance(perturbations.starts, bool) or not isinstance(perturbations.starts, int) or perturbations.starts < 0:
        raise RobustnessError(f"starts {perturbations.starts!r}: a number of episode starts, at least 1 (0: none)")
    if not perturbations.names:
        raise RobustnessError("nothing to measure: give at least one body channel, some starts or the float path")
    seen: set[Channel] = set()
    for name, factors in perturbations.bodies:
        try:
            channel = Channel.parse(name)
        except (ValueError, TypeError) as error:
            raise RobustnessError(f"body {name}: {error}") from None
        if channel in seen:
            raise RobustnessError(f"body {name} is given twice; give each channel's factors once")
        seen.add(channel)
        _check_factors(name, factors)
        for run in runs:
            _check_run_body(run, channel, factors)


def _check_factors(name: str, factors: Sequence[float]) -> None:
    if not factors:
        raise RobustnessError(f"body {name}: no factors; give some, e.g. {name}=0.9,1.1 or {name}=0.8:1.2:9")
    for factor in factors:
        if isinstance(factor, bool) or not isinstance(factor, (int, float)) or not math.isfinite(factor) or factor <= 0:
            raise RobustnessError(f"body {name}: factor {factor!r} is not a finite number above 0")
    repeated = sorted({f for f in factors if list(factors).count(f) > 1})
    if repeated:
        raise RobustnessError(f"body {name}: factor {repeated[0]:g} is given twice; give each factor once")


def _check_run_body(run: RunRecord, channel: Channel, factors: Sequence[float]) -> None:
    if channel not in run.channels:
        raise RobustnessError(
            f"body {channel.name}: {run.directory}'s schedule ({run.schedule}) has no {channel.name} channel (its "
            f"channels: {', '.join(c.name for c in run.channels)}); perturb a channel every run's schedule has"
        )
    final = dict(zip(run.channels, run.phase_bodies()[-1].tolist(), strict=True))
    spec = task_spec(run.task)
    for factor in factors:
        problem = spec.body_problem({**final, channel: final[channel] * factor})
        if problem is not None:
            raise RobustnessError(
                f"body {channel.name}={factor:g}: {run.directory}'s final {channel.name} "
                f"({final[channel]:g}) times {factor:g} is outside what {run.task}'s physics takes: {problem}; "
                f"give factors closer to 1 (`smol-dsl check --task {run.task}` shows the ranges)"
            )


DEFAULT_PERTURBATIONS = Perturbations()
"""`smol-dsl robustness`'s defaults: gear times `DEFAULT_FACTORS`, `DEFAULT_STARTS` other starts, the float path."""
