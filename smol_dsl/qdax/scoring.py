"""A task's scoring in a scheduled body, in QDax's convention.

`scoring_function(task, schedule)` returns `score(genotypes, key, body) -> (fitnesses,
descriptors, extra_scores)`: QDax's `scoring_function(genotypes, key)` with the body added
as a traced argument, so that one compilation serves every phase. It is the rollout the
runner trains with (`Task.score`): the same episode start (the run's seed's), moved into
the body (`tasks.base.start_in_body`), the same masking after the first `done`, and
non-finite results marked as empty (fitness -inf, never inserted into a repertoire).
`extra_scores["transitions"]` holds every step's `QDTransition`, (batch, episode_length)
per field, as QDax's Brax scoring returns them, so emitters that learn from transitions
(PGA-ME's, DCRL-ME's) work unchanged; a program that does not use them compiles them away.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from smol_dsl.errors import ScheduleError
from smol_dsl.language.schedule import Schedule, load
from smol_dsl.seeds import check_seed
from smol_dsl.tasks import make_task
from smol_dsl.tasks.base import Task

if TYPE_CHECKING:
    from collections.abc import Callable

    from brax.envs.base import State

    Score = Callable[[Any, jax.Array, jax.Array], tuple[jax.Array, jax.Array, dict[str, Any]]]


LANE = "lane"
"""The extra score of an elite's lane: its position in the batch it was scored in. A
rollout's last bits depend on its lane (XLA's CPU kernels block a batch's rows, and the
rows of the last block are summed in another order), so the runner's archives keep each
elite's lane (`lanes`, in QDax's `keys_extra_scores`), and a replay that puts the elite
back in its lane of the same program gets the archive's fitness bit for bit."""


def lanes(fitnesses: jax.Array) -> jax.Array:
    """The lane of every result of a scored batch: 0, 1, ..., batch - 1 (int32)."""
    return jnp.arange(jnp.shape(fitnesses)[0], dtype=jnp.int32)


def drop_non_finite(fitnesses: jax.Array, descriptors: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Mark results with a non-finite fitness or descriptor as empty (-inf, never inserted).

    Returns the cleaned fitnesses and descriptors, and which results were finite.
    """
    finite = jnp.isfinite(fitnesses) & jnp.all(jnp.isfinite(descriptors), axis=-1)
    fitnesses = jnp.where(finite, fitnesses, -jnp.inf)
    descriptors = jnp.where(finite[:, None], descriptors, 0.0)
    return fitnesses, descriptors, finite


def as_task(task: Task | str, physics: str | None = None) -> Task:
    """A Task, or the bundled task of that name (its default episode length and network) on
    `physics` (spring by default); a ValueError for a Task simulated on another physics than
    a `physics` given."""
    if isinstance(task, Task):
        if physics is not None and physics != task.physics:
            raise ValueError(
                f"task {task.name} is simulated on {task.physics}, not {physics}: build it with "
                f"make_task({task.name!r}, physics={physics!r}), or leave physics out"
            )
        return task
    if isinstance(task, str):
        return make_task(task, **({} if physics is None else {"physics": physics}))
    raise TypeError(f"task is a smol_dsl Task (smol_dsl.tasks.make_task) or a task's name, not {task!r}")


def as_schedule(schedule: Schedule | str | os.PathLike[str]) -> Schedule:
    """A Schedule, or the schedule of that `.sched` path or bundled name."""
    if isinstance(schedule, Schedule):
        return schedule
    if isinstance(schedule, (str, os.PathLike)):
        return load(schedule)
    raise TypeError(f"schedule is a smol_dsl Schedule (smol_dsl.load) or a .sched path or name, not {schedule!r}")


def task_for(task: Task | str, schedule: Schedule, physics: str | None = None) -> Task:
    """The task (`as_task`) under the schedule's channels; a ValueError (the located message
    of `smol-dsl check --task`) if the schedule names parts the task lacks or may give an
    actuator or a link a factor outside the range the task's physics takes."""
    task = as_task(task, physics)
    try:
        task.spec.check_schedule(schedule, task.physics)
    except ScheduleError as error:
        raise ValueError(str(error)) from None
    return task.with_channels(schedule.channels)


def policy_template(task: Task) -> Any:
    """One policy's parameters (shapes and dtypes only), as `task.init_policies` makes them."""
    one = jax.eval_shape(lambda key: task.init_policies(key, 1), jax.random.key(0))
    return jax.tree.map(lambda leaf: jax.ShapeDtypeStruct(leaf.shape[1:], leaf.dtype), one)


def as_policies(task: Task, genotypes: Any, what: str = "genotypes") -> Any:
    """A batch of the task's policy parameters: `genotypes` as they are if they have the
    task's structure and shapes (a leading batch axis added to each leaf), or unflattened
    if they are a (batch, parameters) array of flat parameters (`ravel_pytree`'s order, as
    CMA emitters make them); a ValueError naming the expected shapes otherwise."""
    template = policy_template(task)
    flat, unravel = ravel_pytree(jax.tree.map(lambda leaf: jnp.zeros(leaf.shape, leaf.dtype), template))
    if isinstance(genotypes, (jax.Array, np.ndarray)) and jax.tree.structure(template).num_leaves != 1:
        if genotypes.ndim == 2 and genotypes.shape[1] == flat.shape[0]:
            return jax.vmap(unravel)(genotypes)
        raise ValueError(
            f"{what} of shape {genotypes.shape} are not {task.name}'s policies: flat genotypes are "
            f"(batch, {flat.shape[0]}) arrays, one row of the policy's {flat.shape[0]} parameters"
        )
    expected = jax.tree.structure(template)
    if jax.tree.structure(genotypes) != expected:
        raise ValueError(
            f"{what} are not a batch of {task.name}'s policies: their structure is not that of {_shapes(template)}"
        )
    leaves = jax.tree.leaves(genotypes)
    batch = {jnp.shape(leaf)[:1] for leaf in leaves}
    shapes_match = all(
        jnp.shape(leaf)[1:] == want.shape for leaf, want in zip(leaves, jax.tree.leaves(template), strict=True)
    )
    if len(batch) != 1 or () in batch or not shapes_match:
        got = jax.tree.map(lambda leaf: tuple(jnp.shape(leaf)), genotypes)
        raise ValueError(
            f"{what} are not a batch of {task.name}'s policies: each leaf is "
            f"(batch, *shape) with the shapes {_shapes(template)}, not {got}"
        )
    return genotypes


def _shapes(template: Any) -> Any:
    return jax.tree.map(lambda leaf: tuple(leaf.shape), template)


def scoring_function(
    task: Task | str,
    schedule: Schedule | str | os.PathLike[str],
    *,
    seed: int = 0,
    start: State | None = None,
    transitions: bool = True,
    physics: str | None = None,
) -> Score:
    """QDax's scoring function of `task` with the body of `schedule` as an argument:
    `score(genotypes, key, body) -> (fitnesses, descriptors, extra_scores)`.

    `body` is a (C,) array of the schedule's channel factors, a row of `phase_bodies`, and
    may be traced (one compilation for every phase). Every episode starts in the episode
    start of `smol-dsl run --seed seed` (or `start`, a state of the task's env made in the
    standard body), moved into the body; `key` is QDax's argument and is not used (episodes
    start deterministically, as in QDax's deterministic Brax scoring).
    A task given by name is built on `physics` (`spring`, the default, or `mjx`); a Task is
    simulated on its own (`make_task(name, physics="mjx")`), and a `physics` given must be it.
    Genotypes are a batch of the task's policy parameters, or a (batch, parameters) array
    of flat ones (CMA emitters). Non-finite results come back as fitness -inf (never
    inserted); `extra_scores["transitions"]` holds QDax's `QDTransition`s unless
    `transitions=False`. Bind the body inside your jitted step:

        update = jax.jit(lambda r, e, k, body: MAPElites(partial(score, body=body), emitter,
                                                          metrics).update(r, e, k))

    A ValueError for a task the schedule's channels do not fit (`smol-dsl check --task`),
    and, when called, for a body of the wrong shape, a concrete body with a factor that is
    not finite and above 0 or outside what the task's physics takes (`check_body`, as `run`
    and `render` refuse it; a traced body is not looked at), or genotypes of other policies.
    """
    schedule = as_schedule(schedule)
    task = task_for(task, schedule, physics)
    seed = check_seed(seed, "seed")
    starts = [start] if start is not None else []  # the episode start, made at the first scoring

    def episode_start() -> State:
        if not starts:  # computed on concrete values even when first asked inside a trace
            with jax.ensure_compile_time_eval():
                starts.append(task.episode_start(seed))
        return starts[0]

    names = ", ".join(channel.name for channel in task.channels)
    size = len(task.channels)

    def rollouts(policies: Any, body: jax.Array) -> tuple[jax.Array, jax.Array, dict[str, Any]]:
        results = task.score(policies, body, episode_start(), transitions=transitions)
        fitnesses, descriptors, _ = drop_non_finite(*results[:2])
        return fitnesses, descriptors, ({"transitions": results[2]} if transitions else {})

    options = task.compiler_options()
    nested = jax.jit(rollouts)  # inside a caller's jitted program, compiled with the caller's options
    alone = jax.jit(rollouts, compiler_options=options) if options else nested

    def score(genotypes: Any, key: jax.Array, body: jax.Array) -> tuple[jax.Array, jax.Array, dict[str, Any]]:
        del key  # deterministic episode start
        if jnp.shape(body) != (size,):
            raise ValueError(
                f"body of shape {jnp.shape(body)}: a body of {task.name} under this schedule is a ({size},) array, "
                f"one factor per channel ({names}): a row of phase_bodies(schedule, num_phases, key)"
            )
        if not isinstance(body, jax.core.Tracer):
            check_body(task, body)
        policies = as_policies(task, genotypes)
        traced = any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves((policies, body)))
        return (nested if traced else alone)(policies, jnp.asarray(body, jnp.float32))

    score.compiler_options = options  # type: ignore[attr-defined]  # for `reevaluate`'s program
    return score


def check_body(task: Task, body: Any) -> None:
    """A ValueError for a concrete body (a factor per channel of `task`) that `smol-dsl`
    refuses: a factor that is not finite and above 0, or a part's factor outside the range
    the task's physics takes (`TaskSpec.body_problem`)."""
    values = np.asarray(body, dtype=np.float64).reshape(-1)
    problem = task.spec.body_problem(dict(zip(task.channels, values.tolist(), strict=True)), task.physics)
    if problem is not None:
        raise ValueError(f"body {values.tolist()}: {problem}")


def compiler_options(task: Task | str) -> dict[str, str] | None:
    """The XLA options to jit your own step with, so that its rollouts compile as fast as
    smol-dsl's on CPUs (`smol_dsl.tasks.compiling`: the same results, bit for bit; None
    where XLA's defaults are used). JAX takes compiler options only at the outermost jit:

        update = jax.jit(step, compiler_options=compiler_options(task))
    """
    return as_task(task).compiler_options()


@dataclass(frozen=True)
class EnvSizes:
    """What QDax's gradient emitters (PGA-ME's, DCRL-ME's) read of an environment."""

    observation_size: int
    action_size: int
    state_descriptor_length: int  # of `QDTransition.state_desc`


def env_sizes(task: Task | str) -> EnvSizes:
    """The sizes QDax's `QualityPGEmitter` and `DCRLEmitter` take from their `env` argument,
    for the transitions of `scoring_function`: pass it as their `env`."""
    task = as_task(task)
    return EnvSizes(task.observation_size, task.env.action_size, task.descriptor_size)


class RunStart(NamedTuple):
    """What `smol-dsl run --seed S` draws before its first generation."""

    key: jax.Array  # the run's key: split once per generation and per phase boundary
    centroids: jax.Array  # the CVT centroids of its archive
    genotypes: Any  # its initial population
    init_key: jax.Array  # the key of its initial scoring (`MAPElites.init`'s)


def run_start(
    task: Task | str, seed: int, *, batch_size: int, num_centroids: int, num_init_cvt_samples: int = 50_000
) -> RunStart:
    """The key, centroids and initial population of `smol-dsl run --seed seed`, so that a
    QDax loop given them (and then `key, sub = split(key)` per generation) follows the same
    random streams. Counts `smol-dsl run` refuses are refused alike (ValueError): a
    `batch_size` below 1, `num_centroids` below 2, fewer CVT samples than centroids."""
    for name, value, least in (("batch_size", batch_size, 1), ("num_centroids", num_centroids, 2)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ValueError(f"{name} is a whole number, not {value!r}")
        if value < least:
            raise ValueError(f"{name} must be at least {least}, not {value}")
    if num_init_cvt_samples < num_centroids:
        raise ValueError(
            f"num_init_cvt_samples must be at least num_centroids ({num_centroids}), not {num_init_cvt_samples}: "
            "each cell's centroid is a mean of samples"
        )
    task = as_task(task)
    key, cvt_key, init_key = seed_keys(check_seed(seed, "seed"))
    centroids = cvt_centroids(num_centroids, task.descriptor_low, task.descriptor_high, num_init_cvt_samples, cvt_key)
    genotypes = task.init_policies(initial_key(init_key), batch_size)
    return RunStart(key, centroids, genotypes, init_key)


def seed_keys(seed: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """A run's keys from its seed, as `smol-dsl run --seed seed` splits it: the run's key,
    its CVT centroids' key and its initial population's."""
    key, cvt_key, init_key = jax.random.split(jax.random.key(seed), 3)
    return key, cvt_key, init_key


def cvt_centroids(
    num_centroids: int, low: tuple[float, ...], high: tuple[float, ...], num_samples: int, key: jax.Array
) -> jax.Array:
    """QDax's CVT tessellation of the descriptor box [low, high] into `num_centroids` cells,
    from `num_samples` uniform samples drawn with `key`."""
    from qdax.core.containers.mapelites_repertoire import compute_cvt_centroids

    return compute_cvt_centroids(
        num_descriptors=len(low),
        num_init_cvt_samples=num_samples,
        num_centroids=num_centroids,
        minval=list(low),
        maxval=list(high),
        key=key,
    )


def initial_key(key: jax.Array) -> jax.Array:
    """The key fresh policies are drawn from in a generation given `key`: the key QDax's
    `MAPElites.update` asks its emitter with (`split(key)[1]`)."""
    return jax.random.split(key)[1]
