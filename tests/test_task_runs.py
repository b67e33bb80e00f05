"""Every bundled task trains under every bundled schedule its body can take, and refuses,
located, the ones it cannot (one sweep per task: one program, its body the union of the
schedules' channels)."""

from __future__ import annotations

import numpy as np
import pytest

import smol_dsl
from smol_dsl.runner import check_config, preset_config, run_experiment, run_sweep
from smol_dsl.tasks import make_task

BUNDLED_TASKS = ("walker2d", "halfcheetah", "ant_omni", "hopper", "ant_uni")


@pytest.mark.parametrize("task_name", BUNDLED_TASKS)
@pytest.mark.slow
def test_every_task_runs_under_every_library_schedule(library, task_name):
    """Every bundled schedule whose channels the task's body has, trained together (one
    program per task, its body the union of their channels); the others refused, located,
    before anything is built."""
    task = make_task(task_name, episode_length=10, hidden_layer_sizes=(8, 8))
    # what the spec says of the body before it is built (archives are checked against it)
    assert task.observation_size == task.spec.observation_size
    assert float(task.env.dt) == pytest.approx(task.spec.step_seconds)
    assert task.env.action_size == len(task.spec.anatomy.actuators)
    config = preset_config(
        task_name,
        "quick",
        evaluations=8 * 12,
        batch_size=8,
        num_phases=10,
        num_centroids=16,
        episode_length=10,
        hidden_layer_sizes=(8, 8),
        num_init_cvt_samples=1000,
    )
    runnable = {}
    for name, schedule in library.items():
        if any(task.spec.anatomy.unknown_targets(c) for c in schedule.channels):
            # leg-damage's left_leg on a body without one
            with pytest.raises(smol_dsl.ScheduleError, match=f"task {task_name} has no actuators named"):
                run_experiment(task, schedule, config)
        else:
            check_config(config, schedule)
            runnable[name] = schedule
    assert {"vanilla", "growth", "low-gravity"} <= set(runnable)
    results = run_sweep(task, list(runnable.values()), [0], config)
    for name, result in zip(runnable, results, strict=True):
        assert result.final["evaluations"] == 96, name
        assert result.final["alpha"] == 1.0, name
        assert result.final["coverage"] > 0 or runnable[name].extinction > 0, name
        assert np.all(
            np.isfinite(np.asarray(result.repertoire.fitnesses)[np.asarray(result.repertoire.fitnesses) > -np.inf])
        ), name
