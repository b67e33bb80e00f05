"""What `smol-dsl robustness` perturbs, and the checks that refuse what cannot be measured
before anything is: `Perturbations` (families of body factors per channel, other episode
starts, the float path, other physics), their names as robustness.csv's `perturbation`
column writes them, what measuring them costs (`estimate`), and `check_perturbations`.
Imports no JAX.

Each perturbation is a family of samples whose corrected archive takes every elite's median
over them (`smol_dsl.rescoring.robustness.median_of_samples`), so a family has an odd number
of samples: its median is then one sample's result, not the midpoint of two. A body family
never mixes x1 (the final body itself: a control, not a change) with changes of it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from smol_dsl.errors import UserInputError, counted
from smol_dsl.runner.footprint import byte_size, host_memory_bytes
from smol_dsl.tasks import task_spec

if TYPE_CHECKING:
    from smol_dsl.language.channels import Channel
    from smol_dsl.rundir import RunRecord

DEFAULT_BODIES = (("gear", (0.9, 0.95, 0.9944)), ("gear", (1.0056, 1.05, 1.1)))
"""Two families of body factors around the final body, one each way: the paper's SMOL step
from one phase to the next (alpha 1.5 to 1 over 90 phases: 0.56%), 5% and 10% less gear, and
as much more. One way each, so that a family's median is not the cancelling of a change and
its opposite; three factors each, so that it is one factor's result."""
DEFAULT_STARTS = 9
MOST_SAMPLES = 999
"""The most samples one perturbation takes (body factors of a family, or starts)."""
MEMORY_SHARE = 0.5
"""The share of the machine's memory the samples' scores, held for the medians, may take."""
BODY = "body"
FLOAT_PATH = "float path"
STARTS = "starts"
PHYSICS = "physics"


class RobustnessError(UserInputError):
    """Runs or perturbations that `smol-dsl robustness` cannot measure."""


def body_name(channel: str, factors: Sequence[float]) -> str:
    """A body family's name, as robustness.csv's `perturbation` column writes it: `body gear
    x1.05` for one factor, `body gear x0.9-0.9944` for factors from 0.9 to 0.9944."""
    low, high = min(factors), max(factors)
    return f"{BODY} {channel} x{low:g}" + ("" if low == high else f"-{high:g}")


def physics_name(physics: str) -> str:
    """Another physics' name as robustness.csv's `perturbation` column writes it: `physics mjx`."""
    return f"{PHYSICS} {physics}"


def channel_of(perturbation: str) -> str | None:
    """The channel of a body family's name (`body_name`); None for another perturbation."""
    if not perturbation.startswith(f"{BODY} "):
        return None
    return perturbation.removeprefix(f"{BODY} ").rsplit(" ", 1)[0]


@dataclass(frozen=True)
class Perturbations:
    """What to re-score every final archive under: `bodies`, families of body factors as
    (channel name, factors) pairs, each factor multiplying that channel's final factor (a
    channel may have several families); `starts` other episode starts (0: none);
    `float_path`, the same body in another program; `physics`, other physics than the runs'
    (`smol_dsl.tasks.physics`), each scoring the same body from the same start: how much of
    an archive carries over to another simulator."""

    bodies: tuple[tuple[str, tuple[float, ...]], ...] = DEFAULT_BODIES
    starts: int = DEFAULT_STARTS
    float_path: bool = True
    physics: tuple[str, ...] = ()

    @property
    def names(self) -> list[str]:
        """The perturbations, as robustness.csv's `perturbation` column names them."""
        return (
            [body_name(_canonical(channel), factors) for channel, factors in self.bodies]
            + ([FLOAT_PATH] if self.float_path else [])
            + [physics_name(physics) for physics in self.physics]
            + ([STARTS] if self.starts else [])
        )

    @property
    def samples(self) -> int:
        """How many times each elite is scored: every body factor, every start, the float
        path, every other physics."""
        return sum(len(factors) for _, factors in self.bodies) + self.starts + int(self.float_path) + len(self.physics)

    @property
    def largest(self) -> int:
        """The most samples of one perturbation: how many scores of each elite a median holds."""
        return max(
            [len(factors) for _, factors in self.bodies] + [self.starts, int(self.float_path), int(bool(self.physics))]
        )


def _canonical(name: str) -> str:
    from smol_dsl.language.channels import Channel

    try:
        return Channel.parse(name).name
    except (ValueError, TypeError):
        return str(name)


@dataclass(frozen=True)
class Estimate:
    """What measuring costs: `episodes` rolled out (every elite of every run once per
    sample), and `held_bytes`, the scores the largest perturbation's median holds at once."""

    runs: int
    samples: int
    episodes: int
    episode_length: int
    held_bytes: int

    def __str__(self) -> str:
        return (
            f"{counted(self.runs, 'run')}, {counted(self.samples, 'sample')} each: {self.episodes:,} episodes of "
            f"{self.episode_length} steps to score, about {byte_size(self.held_bytes)} of scores held for the medians"
        )


def estimate(runs: Sequence[RunRecord], perturbations: Perturbations) -> Estimate:
    """The episodes to score and the memory the medians hold, for finished `runs`."""
    elites = sum(int(run.final_archive().filled.sum()) for run in runs)
    cells = sum(run.config.num_centroids * (1 + task_spec(run.task).descriptor_size) for run in runs)
    return Estimate(
        runs=len(runs),
        samples=perturbations.samples,
        episodes=elites * perturbations.samples,
        episode_length=runs[0].config.episode_length if runs else 0,
        held_bytes=4 * cells * perturbations.largest,
    )


def check_perturbations(runs: Sequence[RunRecord], perturbations: Perturbations) -> None:
    """A RobustnessError for what cannot be measured, before anything is: no runs, a run that
    has not finished, nothing to measure, a start count that is not odd from 1 to
    MOST_SAMPLES (or 0), a body family that is empty, has an even number of factors or over
    MOST_SAMPLES, mixes x1 with changes, or holds a factor that is not finite and above 0 or
    that this channel has already, a channel a run's schedule lacks, a perturbed body outside
    what the task's physics takes (`smol-dsl check --task`'s ranges), another physics that is
    unknown, given twice, a run's own, or one that does not take a run's final body, and
    scores to hold for the medians that would take over MEMORY_SHARE of the machine's memory."""
    from smol_dsl.language.channels import Channel

    if not runs:
        raise RobustnessError("no runs to measure; give run or sweep directories of finished runs")
    unfinished = [run for run in runs if not run.finished or run.archive is None]
    if unfinished:
        raise RobustnessError(
            f"{unfinished[0].directory} has not finished: it has no final archive to re-score"
            + (f" (nor have {counted(len(unfinished) - 1, 'other run')})" if len(unfinished) > 1 else "")
            + "; finish it with `--resume`, or measure the finished runs with --finished-only"
        )
    check_families(perturbations)
    for name, factors in perturbations.bodies:
        channel = Channel.parse(name)
        for run in runs:
            _check_run_body(run, channel, factors)
    for physics in perturbations.physics:
        for run in runs:
            _check_run_physics(run, physics)
    _check_memory(estimate(runs, perturbations))


def check_families(perturbations: Perturbations) -> None:
    """The checks of `check_perturbations` that need no runs (a RobustnessError): the start
    count, each body family's factors, the other physics' names, and that there is something
    to measure."""
    from smol_dsl.language.channels import Channel

    _check_starts(perturbations.starts)
    _check_physics_names(perturbations.physics)
    if not (perturbations.bodies or perturbations.starts or perturbations.float_path or perturbations.physics):
        raise RobustnessError(
            "nothing to measure: give at least one body family, some starts, the float path or another physics"
        )
    seen: dict[Channel, set[float]] = {}
    for name, factors in perturbations.bodies:
        try:
            channel = Channel.parse(name)
        except (ValueError, TypeError) as error:
            raise RobustnessError(f"body {name}: {error}") from None
        _check_factors(channel.name, factors, seen.setdefault(channel, set()))  # no factor twice: names differ


def _check_starts(starts: object) -> None:
    if isinstance(starts, bool) or not isinstance(starts, int) or starts < 0:
        raise RobustnessError(f"starts {starts!r}: a number of episode starts, odd, from 1 to {MOST_SAMPLES} (0: none)")
    if starts > MOST_SAMPLES:
        raise RobustnessError(
            f"starts {starts}: at most {MOST_SAMPLES} other starts (each scores every elite once more, and the "
            f"median holds them all); give fewer, e.g. --starts 99"
        )
    if starts and starts % 2 == 0:
        raise RobustnessError(
            f"starts {starts}: give an odd number of starts ({starts - 1} or {starts + 1}), so that each elite's "
            "median over them is one start's result, not the midpoint of two"
        )


def _check_factors(channel: str, factors: Sequence[float], seen: set[float]) -> None:
    given = f"body {channel}={','.join(f'{f:g}' if isinstance(f, (int, float)) else repr(f) for f in factors)}"
    if not factors:
        raise RobustnessError(f"body {channel}: no factors; give some, e.g. {channel}=0.9,0.95,0.99")
    for factor in factors:
        if isinstance(factor, bool) or not isinstance(factor, (int, float)) or not math.isfinite(factor) or factor <= 0:
            raise RobustnessError(f"{given}: factor {factor!r} is not a finite number above 0")
        if factor in seen:
            raise RobustnessError(f"{given}: factor {factor:g} of {channel} is given twice; give each factor once")
        seen.add(factor)
    if len(factors) > MOST_SAMPLES:
        raise RobustnessError(f"{given}: {len(factors)} factors; a family takes at most {MOST_SAMPLES}")
    if 1 in factors and len(factors) > 1:
        raise RobustnessError(
            f"{given}: x1 is the final body, not a change of it, and would pull the family's median to the "
            f"archive's own result; give it as a family of its own (--body {channel}=1, the control)"
        )
    if len(factors) % 2 == 0:
        raise RobustnessError(
            f"{given}: {counted(len(factors), 'factor')}; a family's median is taken over an odd number of "
            "factors, so that it is one factor's result, not the midpoint of two; add or drop one, or split "
            f"the family in two (--body {channel}=... once per family)"
        )


def _check_run_body(run: RunRecord, channel: Channel, factors: Sequence[float]) -> None:
    if channel not in run.channels:
        raise RobustnessError(
            f"body {channel.name}: {run.directory}'s schedule ({run.schedule}) has no {channel.name} channel (its "
            f"channels: {', '.join(c.name for c in run.channels)}); perturb a channel every run's schedule has"
        )
    final = run.last_phase_body()
    spec = task_spec(run.task)
    for factor in factors:
        problem = spec.body_problem({**final, channel: final[channel] * factor}, run.config.physics)
        if problem is not None:
            raise RobustnessError(
                f"body {channel.name}={factor:g}: {run.directory}'s final {channel.name} "
                f"({final[channel]:g}) times {factor:g} is outside what {run.task}'s physics takes: {problem}; "
                f"give factors closer to 1 (`smol-dsl check --task {run.task} --physics {run.config.physics}` shows "
                "the ranges)"
            )


def _check_physics_names(names: object) -> None:
    from smol_dsl.tasks.physics import physics_problem

    if isinstance(names, str) or not isinstance(names, (tuple, list)):
        raise RobustnessError(f"physics {names!r}: a sequence of physics names, e.g. ('mjx',)")
    for physics in names:
        problem = physics_problem(physics)
        if problem is not None:
            raise RobustnessError(f"other physics: {problem}")
    twice = next((physics for number, physics in enumerate(names) if physics in names[:number]), None)
    if twice is not None:
        raise RobustnessError(f"other physics {twice} is given twice; give each physics once")


def _check_run_physics(run: RunRecord, physics: str) -> None:
    if physics == run.config.physics:
        raise RobustnessError(
            f"other physics {physics}: {run.directory} trained on {physics} already; the float path re-scores "
            "its archive on its own physics in another program, another physics is one the run did not train on"
        )
    final = run.last_phase_body()
    problem = task_spec(run.task).body_problem(final, physics)
    if problem is not None:
        raise RobustnessError(
            f"other physics {physics}: {run.directory}'s final body on {physics}: {problem}; measure such runs "
            f"without {physics} (`smol-dsl check --task {run.task} --physics {physics}` shows the ranges)"
        )


def _check_memory(cost: Estimate) -> None:
    memory = host_memory_bytes()
    if cost.held_bytes > MEMORY_SHARE * memory:
        raise RobustnessError(
            f"measuring {cost} would hold more than {MEMORY_SHARE:.0%} of this machine's memory "
            f"({byte_size(memory)}); give fewer starts or factors, or measure fewer runs at once"
        )


DEFAULT_PERTURBATIONS = Perturbations()
"""`smol-dsl robustness`'s defaults: the gear families of `DEFAULT_BODIES`, `DEFAULT_STARTS`
other starts, the float path."""
