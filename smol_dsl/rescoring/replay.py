"""Elites of a finished run rolled out again by the training's own scoring program, for
drawing their gaits.

`replay_elites` is what `smol_dsl.results.gaits.render_gaits` takes as its `replay`: the
command line hands it down, since rolling out needs the runner's engine and drawing is the
results'. Importing this module imports no JAX; calling `replay_elites` does.

An elite's fitness is bit for bit the archive's when it is scored by the program that
scored it, in the same lane: the engine the run trained on (its devices, the runs trained
together, the runs a device advanced at once, the channels of their bodies: the layout
environment.json records), with the run in its place among those runs and the elite at
its position in the batch (archive.npz's `lanes`). `replay_layout` says when that program
can be built again here; elsewhere (another environment, a run resumed under another
layout, too few devices) the fitness agrees to float rounding only, and the replay says why.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from smol_dsl.rescoring.lanes import lane_batches, lane_index
from smol_dsl.rundir import (
    describe_environment,
    environment_differences,
    latest_environment,
    read_environment_changes,
)

if TYPE_CHECKING:
    from smol_dsl.rundir.archive import Archive
    from smol_dsl.rundir.record import RunRecord

LANES_AT_ONCE = 8
"""Lanes whose poses one replay keeps (`Engine.replay`): every replay takes this many (the
first repeated), so one compiled program serves every click and render."""


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
    rollouts: dict[tuple[int, int], Rollout]  # by (cell, index of the body in the bodies given)
    inexact: str | None = None  # why fitnesses may differ from the archive's by rounding; None: its program and lanes


@dataclass(frozen=True)
class ReplayLayout:
    """The program to replay a run's elites in: `devices` local devices, `runs` runs trained
    together (the run at `index`), `runs_per_step` and the bodies' `channels`; `inexact`
    says why it is not the program that scored the archive (None where it is)."""

    devices: list[Any]
    runs: int
    index: int
    runs_per_step: int | None
    channels: tuple[Any, ...]
    inexact: str | None


def replay_layout(run: RunRecord) -> ReplayLayout:
    """The scoring program of `run` as environment.json records it, on this machine's
    devices; where it cannot be built again, or would not be the same program (another
    environment, an environment changed on resume, a run that recorded no layout), this
    machine's default program for one run, and why its fitnesses agree to rounding only."""
    import jax

    from smol_dsl.language.channels import Channel
    from smol_dsl.runner.layout import default_runs_per_step

    local = list(jax.local_devices())
    fallback = ReplayLayout(local, 1, 0, default_runs_per_step(local), tuple(run.channels), None)  # one run
    recorded = latest_environment(run.directory)
    layout = (recorded or {}).get("layout")
    if recorded is None or not isinstance(layout, dict):
        return dataclasses.replace(fallback, inexact="the run recorded no scoring layout (environment.json)")
    count = int(recorded.get("devices", {}).get("count") or 0)
    platform = recorded.get("devices", {}).get("platform")
    if count > len(local) or platform != local[0].platform:
        return dataclasses.replace(
            fallback,
            inexact=f"it was scored on {count} {platform} device(s); this machine has {len(local)} {local[0].platform}",
        )
    devices = local[:count]
    differences = environment_differences(recorded, describe_environment(devices, physics=run.config.physics))
    changes = read_environment_changes(run.directory)
    inexact = (
        f"it is replayed under another environment ({'; '.join(differences)})"
        if differences
        else "its environment changed when it was resumed (environment.json's changes)"
        if changes
        else None
    )
    return ReplayLayout(
        devices=devices,
        runs=int(layout["runs"]),
        index=int(layout["index"]),
        runs_per_step=layout["runs_per_step"],
        channels=tuple(Channel.parse(name) for name in layout["channels"]),
        inexact=inexact,
    )


def replay_elites(
    run: RunRecord,
    archive: Archive,
    cells: Sequence[int],
    bodies: Sequence[tuple[str, dict[str, float]]],
    *,
    steps: int | None = None,
) -> Replay:
    """Every cell of `archive` in every body (its label, and the factor of each of the
    schedule's channels), rolled out by the program that scored the archive, each elite in
    its lane (`replay_layout`, `lane_batches`): in the body the archive was scored in, the
    fitness and descriptor are the archive's, bit for bit, wherever that program can be
    built again (`Replay.inexact` says why not). The poses come from the same rollout
    compiled to record the positions of the cells' lanes only (`Engine.replay`), so a
    replay holds about one rollout's memory whatever the batch, and brings one batch's
    scores and the cells' poses to the host; `steps` (default: the run's episode length)
    rolls out a longer or shorter episode than the one scored. Rollouts are keyed by
    (cell, the body's index in `bodies`)."""
    import jax

    from smol_dsl.runner.engine import shared_engine, shared_task, stack_runs

    config = run.config
    layout = replay_layout(run)

    def engine_of(episode_length: int) -> Any:
        task = shared_task(config.task, episode_length, tuple(config.hidden_layer_sizes), config.physics)
        shaped = dataclasses.replace(config, episode_length=episode_length)
        return shared_engine(task, shaped, layout.devices, layout.runs_per_step, layout.runs, layout.channels)

    scoring = engine_of(config.episode_length)
    drawing = scoring if not steps or steps == config.episode_length else engine_of(steps)
    runs = scoring.padded_runs(layout.runs)
    episode_start = scoring.task.episode_start(config.seed)
    start, start_pose = stack_runs([episode_start] * runs), np.asarray(episode_start.pipeline_state.q)
    batch, r = config.batch_size, layout.index
    rollouts = {}
    for chunk in lane_batches(cells, archive.lanes, batch):
        index, _ = lane_index(chunk, batch)
        one = jax.tree.map(lambda x, index=index: np.asarray(x)[index], archive.genotypes)
        genotypes = scoring.put_for_every_run(one, runs)  # the batch in every run, as the run scored it
        placed = list(chunk.items())
        for body_index, (_, body) in enumerate(bodies):
            row = [body.get(channel.name, 1.0) for channel in scoring.channels]
            factors = np.asarray([row] * runs, dtype=np.float32)
            fitnesses, descriptors = scoring.score(genotypes, factors, start)
            for first in range(0, len(placed), LANES_AT_ONCE):
                some = placed[first : first + LANES_AT_ONCE]
                lanes = [lane for lane, _ in some] + [some[0][0]] * (LANES_AT_ONCE - len(some))  # one shape
                replayed, q, valid = drawing.replay(genotypes, factors, start, np.asarray(lanes))
                for position, (lane, cell) in enumerate(some):
                    rollouts[cell, body_index] = Rollout(
                        fitness=float(fitnesses[r, lane]),
                        descriptor=np.asarray(descriptors[r, lane]),
                        poses=np.concatenate([start_pose[None], q[r, position][valid[r, position]]]),  # until it ends
                        scored=drawing is not scoring or bool(replayed[r, position] == fitnesses[r, lane]),
                    )
    return Replay(
        model=drawing.task.env.sys.mj_model,
        dt=float(drawing.task.env.dt),
        rollouts=rollouts,
        inexact=layout.inexact,
    )
