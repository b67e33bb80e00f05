"""The bundled Brax MAP-Elites runner: phased training while a schedule changes the body.

Modules, one concept each: `config` (the checks of a run's settings; no JAX), `plan`
(what is to be trained: `PlannedRun` and the checks of the runs before anything is made),
`map_elites` (one run's step on QDax), `layout` (runs and populations on devices; no JAX),
`engine` (that step over runs and devices), `core` (the algorithm: pure functions that
start every run's state, advance it a generation and take it across a phase boundary),
`training` (the host loop around the core: metrics, progress, checkpoints, resume), `sweep`
(the one entry: a run or a sweep planned, checked and sized once, then trained; `run` is a
sweep of one), `directories` (setting up, locking and checking run and
sweep directories), `checkpoint`, `lock`, `footprint` (memory), `estimate` (`--dry-run`'s
measurement), `progress` (the bar). Finished runs are scored again by `smol_dsl.rescoring`,
the layer above. A run directory's files are `smol_dsl.rundir`'s (RunConfig and the
presets included); figures are drawn from them after training (`smol_dsl.results.run_figures`).
Importing this package imports JAX only when an entry point is used.
"""

from __future__ import annotations

from smol_dsl.lazy import lazy_names
from smol_dsl.rundir.config import RunConfig
from smol_dsl.rundir.presets import PRESETS, preset_config
from smol_dsl.runner.config import ConfigError, RunError, check_config

_LAZY = {
    "Archive": "smol_dsl.rundir",
    "load_archive": "smol_dsl.rundir",
    "RunResult": "smol_dsl.runner.training",
    "schedule_key": "smol_dsl.seeds",
    "run_experiment": "smol_dsl.runner.run",
    "run_sweep": "smol_dsl.runner.sweep",
}

__all__ = [
    "PRESETS",
    "Archive",
    "ConfigError",
    "RunConfig",
    "RunError",
    "RunResult",
    "check_config",
    "load_archive",
    "preset_config",
    "run_experiment",
    "run_sweep",
    "schedule_key",
]

__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
