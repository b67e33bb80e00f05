"""Runs sharded over devices equal the same runs on one device: a sweep's runs split
between two CPU devices (padded to an even count), stepped one at a time or all at once,
and one run whose population is split between two devices."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

MULTI_DEVICE = """
import json, sys
import jax, numpy as np, smol_dsl
from smol_dsl.runner import preset_config, run_sweep
config = preset_config("walker2d", "quick", evaluations=208, batch_size=16, num_phases=10, num_centroids=32,
                       episode_length=20)
schedules = [smol_dsl.load("human"), smol_dsl.load("extinction-50"), smol_dsl.load("smol")]  # 3 runs: padded
out = {}
one, two = jax.devices()[:1], jax.devices()
for name, runs_of, devices, per_step in (
    ("one", schedules, one, -1),
    ("two", schedules, two, -1),
    ("two-vmapped", schedules, two, None),
    ("one-run-two-devices", schedules[:1], two, -1),  # its population is split between them
):
    runs = run_sweep("walker2d", runs_of, [0], config, devices=devices, runs_per_step=per_step)
    out[name] = [dict(fitnesses=np.asarray(r.repertoire.fitnesses).tolist(), rows=r.metrics) for r in runs]
out["devices"] = len(jax.devices())
with open(sys.argv[1], "w") as file:
    json.dump(out, file)
"""


@pytest.mark.slow
def test_runs_sharded_over_two_devices_equal_one_device(tmp_path):
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
    result = tmp_path / "result.json"
    done = subprocess.run(
        [sys.executable, "-c", MULTI_DEVICE, str(result)], env=env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr
    out = json.loads(result.read_text())
    assert out["devices"] == 2
    out["one-run"] = out["one"][:1]  # a run of a sweep is the run alone (test_sweep)
    for reference, name in (("one", "two"), ("one", "two-vmapped"), ("one-run", "one-run-two-devices")):
        for one, other in zip(out[reference], out[name], strict=True):
            a, b = np.asarray(one["fitnesses"]), np.asarray(other["fitnesses"])
            np.testing.assert_array_equal(a > -np.inf, b > -np.inf)
            np.testing.assert_allclose(a, b, rtol=1e-5)
            for x, y in zip(one["rows"], other["rows"], strict=True):
                for field in ("event", "evaluations", "reevaluations", "alpha", "non_finite"):
                    assert x[field] == y[field]
                assert x["max_fitness"] == pytest.approx(y["max_fitness"], rel=1e-5)
