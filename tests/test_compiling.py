"""The rollouts' compiler options: used where measured bit for bit, and nowhere else."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from smol_dsl.tasks import compiling, make_task, task_names
from smol_dsl.tasks.compiling import EXACT_TASKS, FAST_CPU_OPTIONS, compiler_options, jax_line

EXACT_HERE = sorted(EXACT_TASKS.get(jax_line(), ()))


def test_every_measured_task_exists_and_this_jax_line_was_measured():
    """The table names real tasks, and the tested jax lines (constraints/) are in it."""
    for tasks in EXACT_TASKS.values():
        assert tasks <= set(task_names())
    assert jax_line() in EXACT_TASKS, f"jax {jax.__version__}: measure which tasks the options leave bit for bit"


def test_options_only_on_cpus_for_measured_tasks():
    for name in task_names():
        expected = FAST_CPU_OPTIONS if name in EXACT_HERE else None
        assert compiler_options(name, "cpu") == expected
        assert compiler_options(name, "gpu") is None
    assert make_task("walker2d").compiler_options("tpu") is None


def test_an_option_xla_refuses_falls_back_to_its_defaults(monkeypatch):
    """A later XLA that no longer knows the experimental option compiles with its defaults."""
    monkeypatch.setattr(compiling, "FAST_CPU_OPTIONS", {"xla_cpu_no_such_option_anywhere": "1"})
    compiler_options.cache_clear()
    try:
        assert compiler_options(EXACT_HERE[0], "cpu") is None
    finally:
        compiler_options.cache_clear()


@pytest.mark.slow
@pytest.mark.parametrize("name", EXACT_HERE)
def test_the_options_leave_every_result_bit_for_bit(name):
    """Fitnesses, descriptors and every transition of random policies in a body of three
    channels: the same bits as XLA's default compilation (tiny sizes show a difference where
    there is one: jax 0.10's ant differs within 40 steps)."""
    task = make_task(name, episode_length=40, hidden_layer_sizes=(8, 8)).with_channels(("gear", "mass", "friction"))
    params = task.init_policies(jax.random.key(1), 8)
    args = (params, jnp.asarray([1.2, 0.9, 1.1]), task.episode_start(3))

    def score(params, body, start):
        return task.score(params, body, start, transitions=True)

    default = jax.jit(score)(*args)
    fast = jax.jit(score, compiler_options=task.compiler_options("cpu"))(*args)
    assert task.compiler_options("cpu") == FAST_CPU_OPTIONS
    for ours, theirs in zip(jax.tree.leaves(fast), jax.tree.leaves(default), strict=True):
        np.testing.assert_array_equal(np.asarray(ours), np.asarray(theirs))
