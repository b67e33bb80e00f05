"""Shared fixtures: the bundled library, parsed and verified once per test session, and the
Brax tasks the task tests share (each compiles its scoring function once per session)."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("MPLBACKEND", "Agg")

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
