"""`smol_dsl.rescoring.replay`: a finished run's elites rolled out again in the program that
scored its archive, each in its lane, give the archive's fitnesses and descriptors bit for
bit (a run's and every run of a sweep trained together); where that program cannot be
built again, the replay says why."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from small_runs import copy_of

from smol_dsl.rescoring.lanes import lane_batches
from smol_dsl.rescoring.replay import replay_elites, replay_layout
from smol_dsl.results.gaits import resolve_bodies
from smol_dsl.rundir import ENVIRONMENT_FILE, load_archive, read_run


def replays_bit_for_bit(directory) -> int:
    """Replay every elite of the run in its final body: each fitness and descriptor is the
    archive's, exactly. Returns how many elites were compared."""
    run = read_run(directory)
    archive = load_archive(directory)
    cells = [int(cell) for cell in np.flatnonzero(archive.filled)]
    replay = replay_elites(run, archive, cells, resolve_bodies(["final"], run))
    assert replay.inexact is None
    for cell in cells:
        rollout = replay.rollouts[cell, 0]
        assert rollout.fitness == float(archive.fitnesses[cell]), cell
        np.testing.assert_array_equal(rollout.descriptor, np.asarray(archive.descriptors[cell]))
        assert rollout.scored
    return len(cells)


def test_every_elite_of_a_run_replays_to_the_archive_bit_for_bit(small_run):
    assert replays_bit_for_bit(small_run) > 1


def test_every_elite_of_every_run_of_a_sweep_replays_to_its_archive_bit_for_bit(mixed_sweep):
    sweep, _, results = mixed_sweep
    directories = sorted(path.parent for path in sweep.rglob("metrics.csv"))
    assert len(directories) == len(results) == 3
    for directory in directories:
        layout = json.loads((directory / ENVIRONMENT_FILE).read_text())["environment"]["layout"]
        assert layout["runs"] == 3
        assert replays_bit_for_bit(directory) >= 1  # leg-damage gathers its few elites into one cell


def test_a_run_resumed_under_another_environment_replays_within_rounding_and_says_so(small_run, tmp_path):
    out = copy_of(small_run, tmp_path)
    path = out / ENVIRONMENT_FILE
    data = json.loads(path.read_text())
    data["changes"].append({"environment": data["environment"], "differences": ["devices count 2 -> 1"]})
    path.write_text(json.dumps(data))
    assert "changed when it was resumed" in replay_layout(read_run(out)).inexact
    del data["environment"]["layout"]
    data["changes"] = []
    path.write_text(json.dumps(data))
    assert "recorded no scoring layout" in replay_layout(read_run(out)).inexact


@given(
    st.lists(st.integers(0, 63), min_size=1, max_size=40, unique=True),
    st.lists(st.integers(-1, 9), min_size=64, max_size=64),
)
def test_lane_batches_put_every_cell_once_and_in_its_own_lane_where_known(cells, lanes):
    lanes = np.asarray(lanes)
    batches = lane_batches(cells, lanes, 8)
    placed = [cell for batch in batches for cell in batch.values()]
    assert sorted(placed) == sorted(cells)
    for batch in batches:
        assert all(0 <= lane < 8 for lane in batch)
        for lane, cell in batch.items():
            assert lanes[cell] in (lane, -1, 8, 9)  # its own lane, or a free one if unknown or out of the batch
    known = [int(lanes[cell]) for cell in cells if 0 <= lanes[cell] < 8]
    least = max([*(known.count(lane) for lane in set(known)), -(-len(cells) // 8)])
    assert len(batches) == least


def test_a_replay_at_a_large_batch_holds_one_rollout_and_brings_back_its_cells_poses_only(small_run, monkeypatch):
    """A click on a paper-sized sweep (30 runs x 8,192 lanes x 1,000 steps) must not keep or
    fetch every lane's poses (9 GB): at a large batch and short episodes, the replay's
    program needs about the scoring program's memory, and the host gets the batch's scores
    and the replayed cell's poses, not the batch's. (The archive was scored at batch 16, so
    its fitness is not expected here: the replay must reach the scoring program's.)"""
    import jax

    from smol_dsl.rescoring.replay import LANES_AT_ONCE
    from smol_dsl.runner.engine import shared_engine, stack_runs

    run = read_run(small_run)
    batch, steps = 1024, 2
    big = dataclasses.replace(run, config=dataclasses.replace(run.config, batch_size=batch, episode_length=steps))
    archive = load_archive(small_run)
    fetched = []
    device_get = jax.device_get

    def counted(tree):
        host = device_get(tree)
        fetched.append(sum(np.asarray(leaf).nbytes for leaf in jax.tree.leaves(host)))
        return host

    monkeypatch.setattr(jax, "device_get", counted)
    replay = replay_elites(big, archive, [archive.best_cell], resolve_bodies(["final"], big))
    monkeypatch.undo()
    rollout = replay.rollouts[archive.best_cell, 0]
    nq = rollout.poses.shape[1]
    assert rollout.scored and rollout.poses.shape == (steps + 1, nq)  # the start, then every step
    layout = replay_layout(big)
    runs, descriptors = layout.runs, archive.descriptors.shape[1]
    scores = runs * batch * (1 + descriptors) * 4  # the batch's fitnesses and descriptors, float32
    poses = runs * LANES_AT_ONCE * (4 + steps * (nq * 4 + 1))  # the lanes' fitnesses, positions, steps counted
    assert sum(fetched) <= scores + poses + 1024, (fetched, scores, poses)  # not batch x steps x nq floats

    engine = shared_engine(big.task, big.config, layout.devices, layout.runs_per_step, layout.runs, layout.channels)
    one = jax.tree.map(lambda x: np.asarray(x)[np.zeros(batch, dtype=int)], archive.genotypes)
    genotypes = engine.put_for_every_run(one, runs)
    bodies = engine.put(np.ones((runs, len(engine.channels)), np.float32))
    starts = engine.put(stack_runs([engine.task.episode_start(big.seed)] * runs))
    lanes = engine.put(np.zeros((runs, LANES_AT_ONCE), np.int32))
    scoring = engine._scores.lower(genotypes, bodies, starts).compile().memory_analysis()
    replaying = engine._replays.lower(genotypes, bodies, starts, lanes).compile().memory_analysis()
    one_rollout = scoring.temp_size_in_bytes + scoring.output_size_in_bytes
    assert replaying.output_size_in_bytes <= poses + 64  # and the table of its three results
    assert replaying.temp_size_in_bytes + replaying.output_size_in_bytes <= 1.25 * one_rollout, (replaying, scoring)
