"""Elites of a finished run rolled out again by the training's own scoring program, for
drawing their gaits.

`replay_elites` is what `smol_dsl.results.gaits.render_gaits` takes as its `replay`: the
command line hands it down, since rolling out needs the runner's engine and drawing is the
results'. Importing this module imports no JAX; calling `replay_elites` does.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from smol_dsl.rundir.archive import Archive
    from smol_dsl.rundir.record import RunRecord


@dataclass(frozen=True)
class Rollout:
    """One elite rolled out in one body."""

    fitness: float  # the scoring program's, over the run's episode
    descriptor: np.ndarray
    poses: np.ndarray  # (frames, nq): the episode start's positions, then every step's until the episode ends
    scored: bool  # the poses' rollout reached the scored fitness, bit for bit


@dataclass(frozen=True)
class Replay:
    """Every elite's rollout in every body, and what drawing them takes."""

    model: Any  # the task's `mujoco.MjModel`
    dt: float  # seconds per environment step
    rollouts: dict[tuple[int, str], Rollout]  # by (cell, body label)


def replay_elites(
    run: RunRecord,
    archive: Archive,
    cells: Sequence[int],
    bodies: Sequence[tuple[str, dict[str, float]]],
    *,
    steps: int | None = None,
) -> Replay:
    """Every cell of `archive` in every body (its label, and the factor of each of the
    schedule's channels), rolled out by the run's engine: the same batch size, devices and
    episode start, so that in the body the archive was scored in the fitness and descriptor
    are the archive's, bit for bit, on the device layout the run trained on. The poses come
    from the same rollout on the same layout, recording positions; `steps` (default: the
    run's episode length) rolls out a longer or shorter episode than the one scored."""
    import jax

    from smol_dsl.language.channels import Channel
    from smol_dsl.runner.engine import shared_engine, shared_task, stack_runs
    from smol_dsl.runner.layout import default_runs_per_step

    config = run.config
    channels = tuple(Channel.parse(name) for name in bodies[0][1])
    devices = tuple(jax.local_devices())

    def engine_of(episode_length: int) -> Any:
        task = shared_task(config.task, episode_length, tuple(config.hidden_layer_sizes))
        shaped = dataclasses.replace(config, episode_length=episode_length)
        return shared_engine(task, shaped, devices, default_runs_per_step(list(devices)), 1, channels)

    scoring = engine_of(config.episode_length)
    drawing = scoring if not steps or steps == config.episode_length else engine_of(steps)
    episode_start = scoring.task.episode_start(config.seed)
    start, start_pose = stack_runs([episode_start]), np.asarray(episode_start.pipeline_state.q)
    batch = config.batch_size
    rollouts = {}
    for label, body in bodies:
        factors = np.asarray([list(body.values())], dtype=np.float32)
        for first in range(0, len(cells), batch):
            chunk = list(cells[first : first + batch])
            padded = chunk + [chunk[0]] * (batch - len(chunk))
            genotypes = jax.tree.map(lambda x, index=padded: np.asarray(x)[index][None], archive.genotypes)
            fitnesses, descriptors = scoring.score(genotypes, factors, start)
            replayed, _, q, valid = drawing.replay(genotypes, factors, start)
            for k, cell in enumerate(chunk):
                rollouts[cell, label] = Rollout(
                    fitness=float(fitnesses[0, k]),
                    descriptor=np.asarray(descriptors[0, k]),
                    poses=np.concatenate([start_pose[None], q[0, k][valid[0, k]]]),  # until the episode ends
                    scored=drawing is not scoring or bool(replayed[0, k] == fitnesses[0, k]),
                )
    return Replay(model=drawing.task.env.sys.mj_model, dt=float(drawing.task.env.dt), rollouts=rollouts)
