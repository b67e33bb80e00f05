"""Shared test set-up: JAX on the CPU with a compilation cache for the session, the bundled
library parsed and verified once, and the Brax tasks the task tests share.

`pytest -m "not slow"` leaves out what compiles Brax physics or trains (the edit loop);
tests that use a compiling fixture are marked here, the others in their own files. In that
run the property and fuzz tests draw an eighth of their examples, the same every run
(tests/budget.py).

Compile once per session: JAX's persistent compilation cache is on for the test session and
for every subprocess it starts (the CLI runs of the resume and kill tests inherit the
environment), in a directory of this session's unless `JAX_COMPILATION_CACHE_DIR` names one
(set it to keep compilations from one session to the next, e.g. in the edit loop). A program
that another test or process compiled is then loaded, not compiled again; what it computes
is the same executable, bit for bit. Every program is kept, however quick to compile: an
episode's start is computed eagerly (as QDax does), op by op, and loading those few hundred
small programs costs a fraction of compiling them in each process.

Two CPU devices, whatever the machine (unless XLA_FLAGS already says how many): what
`smol-dsl run` splits a 2-core machine into. The CLI subprocesses inherit the flag, so a run
in this process and the same run from the command line are the same programs, compiled
once, with equal results (tests/small_runs.py gives both one size); test_devices compares
one device with two.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("MPLBACKEND", "Agg")
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:  # before JAX is imported: it reads these once
    _cache = tempfile.mkdtemp(prefix="smol-dsl-test-jax-cache-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _cache
    atexit.register(shutil.rmtree, _cache, ignore_errors=True)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")  # also the ops of an eager reset
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):  # two CPU devices
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2").strip()

import smol_dsl


def pytest_configure(config: pytest.Config) -> None:
    """A run that leaves the slow tests out is the fast tier: its property and fuzz tests draw
    a share of their examples (budget.py), the same ones every run (derandomized), so that the
    edit loop's verdict does not change from one run to the next."""
    import budget
    from hypothesis import settings

    budget.fast_tier = "not slow" in (config.getoption("markexpr") or "")
    if budget.fast_tier:
        settings.register_profile("fast-tier", derandomize=True)
        settings.load_profile("fast-tier")


COMPILING_FIXTURES = {"small_run", "small_result", "mixed_sweep", "walker", "cheetah", "robust_sweep", "explored_sweep"}
"""Fixtures that build and compile Brax tasks: a test that uses one is `slow`."""


SHARED_WORKERS = {
    "test_runner": "small-runs",
    "test_devices": "small-runs",
    "test_sweep": "small-runs",
    "test_storage_errors": "small-runs",
    "test_run_directories": "small-runs",
    "test_checkpoint": "small-runs",
    "test_channel_runs": "small-runs",
    "test_seeds": "small-runs",
    "test_gaits": "small-runs",
    "test_report_page": "small-runs",
    "test_environment": "small-runs",
    "test_entry_points": "small-runs",
    "test_replay": "small-runs",
    "test_robustness": "small-runs",
    "test_explorer": "small-runs",
    "test_tasks": "brax-tasks",
    "test_body": "brax-tasks",
    "test_install": "builds",
    "test_wheelhouse": "builds",
}
"""Test files that pytest-xdist runs in one worker: those that train at the one size of
small_runs (they share the session's small run and the engines of its settings), and
those that share the `walker` and `cheetah` tasks, and those that build smol-dsl's wheel in the
checkout (pip builds in place: two builds at once would share its build/ folder). Every other file is a unit of its own,
as with `--dist loadfile`."""


LONGEST_UNITS = (
    "small-runs",
    "brax-tasks",
    "test_footprint",
    "test_properties",
    "test_qdax_examples",
    "test_paced_runs",
    "test_accelerator",
    "test_benchmarks",
    "test_qdax",
    "test_task_runs",
)
"""The units that take minutes on 2 cores (in that order, as measured with --durations):
handed out first, so that the session does not end waiting on one of them while the other
workers are idle; the many short files fill in at the end."""


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """`--dist loadfile` (the default in pyproject.toml), with the files of SHARED_WORKERS
    together: each unit goes whole to the next free worker, LONGEST_UNITS first, then the
    others by their number of tests, the largest first."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class SharedWorkers(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            path = nodeid.split("::", 1)[0]
            return SHARED_WORKERS.get(Path(path).stem, path)

        def _assign_work_unit(self, node: Any) -> None:
            for unit in reversed(LONGEST_UNITS):
                for scope in [scope for scope in self.workqueue if Path(scope).stem == unit]:
                    self.workqueue.move_to_end(scope, last=False)
            super()._assign_work_unit(node)

    return SharedWorkers(config, log)


@pytest.hookimpl(tryfirst=True)  # before `-m` selects by markers
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark `slow` every test that uses a compiling fixture (tests that compile or train by
    themselves carry the marker in their file)."""
    for item in items:
        if COMPILING_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session")
def library() -> dict[str, smol_dsl.Schedule]:
    """Every bundled schedule by name, verified once."""
    return {name: smol_dsl.load(name) for name in smol_dsl.library_names()}


TASK_EPISODE = 50  # steps of the shared tasks' episodes


@pytest.fixture(scope="session")
def walker():
    """walker2d with 50-step episodes (test_tasks, test_body)."""
    from smol_dsl.tasks import make_task

    return make_task("walker2d", episode_length=TASK_EPISODE)


@pytest.fixture(scope="session")
def small_run(small_result):
    """The directory of `small_result`: what `smol-dsl run walker2d human` with
    small_runs.FLAGS writes, but the figures (test_run_directories, test_storage_errors,
    test_checkpoint, test_runner)."""
    return small_result.out_dir


@pytest.fixture(scope="session")
def small_result(library, tmp_path_factory):
    """walker2d under SMOL-Human, seed 0, at small_runs.CONFIG, uninterrupted: its RunResult."""
    from small_runs import CONFIG

    from smol_dsl.runner import run_experiment

    out = tmp_path_factory.mktemp("small-run") / "run"
    return run_experiment("walker2d", library["human"], CONFIG, out_dir=out)


@pytest.fixture(scope="session")
def cheetah():
    """halfcheetah with 50-step episodes (test_tasks, test_body)."""
    from smol_dsl.tasks import make_task

    return make_task("halfcheetah", episode_length=TASK_EPISODE)


@pytest.fixture(scope="session")
def mixed_sweep(tmp_path_factory):
    """vanilla (gear only), growth (gear and mass) and leg-damage (a damaged final left leg)
    trained together at small_runs.CONFIG, seed 0: the program's body is the union of their
    channels, and its three runs are padded to four on two devices (test_channel_runs,
    test_devices). (sweep directory, config, results)"""
    from small_runs import CONFIG, MIXED_SWEEP

    from smol_dsl.runner import run_sweep

    out = tmp_path_factory.mktemp("mixed") / "sweep"
    schedules = [smol_dsl.load(name) for name in MIXED_SWEEP]
    return out, CONFIG, run_sweep("walker2d", schedules, [0], CONFIG, out_dir=out)
