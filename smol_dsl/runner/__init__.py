"""The bundled Brax MAP-Elites runner: phased training under a schedule of actuator strength."""

from smol_dsl.runner.checkpoint import Archive, load_archive
from smol_dsl.runner.config import PRESETS, RunConfig, check_config, preset_config
from smol_dsl.runner.run import RunError, RunResult, run_experiment, schedule_key
from smol_dsl.runner.sweep import run_sweep

__all__ = [
    "PRESETS",
    "Archive",
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
