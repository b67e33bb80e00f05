"""Runs sharded over devices equal the same runs on one device: a sweep's runs split
between two CPU devices (three, padded to four), stepped one at a time or all at once, and
one run whose population is split between two devices (the test session has two CPU
devices: conftest.py)."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from small_runs import CONFIG, MIXED_SWEEP

import smol_dsl
from smol_dsl.runner import run_experiment, run_sweep

pytestmark = pytest.mark.slow  # trains


@pytest.fixture(scope="module")
def layouts(mixed_sweep):
    """The runs of the mixed sweep in each layout, and its first run alone."""
    schedules = [smol_dsl.load(name) for name in MIXED_SWEEP]
    one, two = jax.devices()[:1], jax.devices()
    assert len(two) == 2
    _, _, on_two = mixed_sweep  # one run at a time on each device
    runs = {
        "one": run_sweep("walker2d", schedules, [0], CONFIG, devices=one),
        "two": on_two,
        "two-vmapped": run_sweep("walker2d", schedules, [0], CONFIG, devices=two, runs_per_step=None),
    }
    runs["one-run"] = runs["one"][:1]  # a run of a sweep is the run alone (test_sweep, test_channel_runs)
    runs["one-run-two-devices"] = [run_experiment("walker2d", schedules[0], CONFIG)]  # its population split
    return runs


@pytest.mark.parametrize(
    ("reference", "layout"), [("one", "two"), ("one", "two-vmapped"), ("one-run", "one-run-two-devices")]
)
def test_runs_sharded_over_two_devices_equal_one_device(layouts, reference, layout):
    for one, other in zip(layouts[reference], layouts[layout], strict=True):
        a, b = np.asarray(one.repertoire.fitnesses), np.asarray(other.repertoire.fitnesses)
        np.testing.assert_array_equal(a > -np.inf, b > -np.inf)
        np.testing.assert_allclose(a, b, rtol=1e-5)
        for x, y in zip(one.metrics, other.metrics, strict=True):
            for field in ("event", "evaluations", "reevaluations", "alpha", "non_finite"):
                assert x[field] == y[field]
            assert x["max_fitness"] == pytest.approx(y["max_fitness"], rel=1e-5)
