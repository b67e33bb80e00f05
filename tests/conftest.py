"""Shared test set-up: JAX on the CPU with a compilation cache for the session, the bundled
library parsed and verified once, and the Brax tasks the task tests share.

Compile once per session: JAX's persistent compilation cache is on for the test session and
for every subprocess it starts (the CLI runs of the resume and kill tests inherit the
environment), in a directory of this session's unless `JAX_COMPILATION_CACHE_DIR` names one
(set it to keep compilations from one session to the next, e.g. in the edit loop). A program
that another test or process compiled is then loaded, not compiled again; what it computes
is the same executable, bit for bit.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile

import pytest

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("MPLBACKEND", "Agg")
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:  # before JAX is imported: it reads these once
    _cache = tempfile.mkdtemp(prefix="smol-dsl-test-jax-cache-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _cache
    atexit.register(shutil.rmtree, _cache, ignore_errors=True)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")  # Brax programs, not every small op
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")

import smol_dsl


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
def cheetah():
    """halfcheetah with 50-step episodes (test_tasks, test_body)."""
    from smol_dsl.tasks import make_task

    return make_task("halfcheetah", episode_length=TASK_EPISODE)
