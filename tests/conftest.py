"""Shared fixtures: the bundled library, parsed and verified once per test session."""

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
