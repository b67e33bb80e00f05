"""`smol_dsl.rescoring.replay`: a finished run's elites rolled out again in the program that
scored its archive, each in its lane, give the archive's fitnesses and descriptors bit for
bit (a run's and every run of a sweep trained together); where that program cannot be
built again, the replay says why."""

from __future__ import annotations

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
