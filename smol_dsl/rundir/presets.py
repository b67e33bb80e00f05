"""The presets: a run's settings by name, per task. `paper` is the paper's, `quick` is sized
for a 2-core CPU; `preset_config` makes the `RunConfig` of one, with fields overridden.

The runner starts runs from them, and the report names how a run's settings differ from
the paper's (`smol_dsl.results.paper`), so they sit here, below both. Imports neither JAX
nor Brax."""

from __future__ import annotations

from typing import Any

from smol_dsl.rundir.config import RunConfig
from smol_dsl.tasks import PRESET_NAMES, task_spec

# The paper (Table "Hyperparameters for each task"): 1e7 evaluations, 100 phases, 1024 CVT
# centroids, iso+line variation; per task, the batch, episode and network sizes of its spec.
PAPER_COMMON = dict(evaluations=10_000_000, num_phases=100, num_centroids=1024)
# Sized for a 2-core CPU; per task, the batch, episode, network and budget of its quick preset.
QUICK_COMMON = dict(num_phases=20, num_centroids=256)
COMMON = {"paper": PAPER_COMMON, "quick": QUICK_COMMON}

PRESETS = PRESET_NAMES


def preset_config(task: str, preset: str = "quick", **overrides: Any) -> RunConfig:
    """The preset's settings for a task, with any field overridden (None means keep)."""
    spec = task_spec(task)  # a ValueError listing the tasks for an unknown one
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; the presets are {', '.join(PRESETS)}")
    values: dict[str, Any] = {**COMMON[preset], **spec.presets[preset]}
    values.update({k: v for k, v in overrides.items() if v is not None})
    return RunConfig(task=task, preset=preset, **values)
