"""The physics a task simulates its body with: Brax's `spring` (the paper's) or MuJoCo's MJX.

A physics is a name a run records (config.json, environment.json) and a Brax backend the
task's environment is built with. Both simulate the same MuJoCo model (Brax loads the
environment's MJCF for either); they differ in how: `spring` is Brax's own impulse-based
pipeline, which Brax no longer maintains; `mjx` is MuJoCo's soft-constraint dynamics in JAX
(MuJoCo XLA, shipped with `mujoco`), which reads the model's fields as MuJoCo does. A body
is written into the fields its physics reads (`tasks.body` for spring, `tasks.mjx_body` for
MJX).

Importing this module imports neither JAX nor Brax.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import metadata

from smol_dsl.errors import UserInputError


@dataclass(frozen=True)
class Physics:
    """A physics a task can be simulated with: its name, the Brax backend that runs it, the
    package that implements it (recorded with its version), what to call it in a sentence,
    and a line for help texts."""

    name: str
    backend: str
    package: str
    title: str
    help: str


PHYSICS: dict[str, Physics] = {
    physics.name: physics
    for physics in (
        Physics("spring", "spring", "brax", "Brax's spring pipeline", "Brax's spring pipeline, as in the paper"),
        Physics("mjx", "mjx", "mujoco-mjx", "MuJoCo's MJX", "MuJoCo's MJX (MuJoCo XLA) in JAX, which MuJoCo maintains"),
    )
}
PHYSICS_NAMES = tuple(PHYSICS)
DEFAULT_PHYSICS = "spring"
MJX_IMPLEMENTATION = "jax"
"""The implementation MJX runs smol-dsl's tasks with (MJX's `impl`): MJX-JAX. MuJoCo Warp is
not wired (docs/runner.md#physics-spring-or-mjx)."""


def physics_problem(name: object) -> str | None:
    """What is wrong with a physics name, in words (with the names there are), or None."""
    if isinstance(name, str) and name in PHYSICS:
        return None
    return f"unknown physics {name!r}; the physics are {', '.join(PHYSICS_NAMES)} ({DEFAULT_PHYSICS} by default)"


def check_physics(name: object) -> Physics:
    """The physics of a name; a ValueError naming the physics there are otherwise."""
    problem = physics_problem(name)
    if problem is not None:
        raise ValueError(problem)
    return PHYSICS[name]  # type: ignore[index]


def physics_record(name: str) -> dict[str, str | None]:
    """What environment.json records of a run's physics: its name, the package that
    implements it and that package's installed version, and how MJX runs it (MJX-JAX)."""
    physics = check_physics(name)
    try:
        version: str | None = metadata.version(physics.package)
    except metadata.PackageNotFoundError:
        version = None
    record: dict[str, str | None] = {"name": physics.name, "package": physics.package, "version": version}
    if physics.name == "mjx":
        record["implementation"] = MJX_IMPLEMENTATION  # what `check_mjx_implementation` holds
    return record


def check_mjx_implementation(implementation: str) -> None:
    """Refuse a model MJX built for an implementation other than MJX-JAX (MuJoCo Warp, which
    MJX picks on an NVIDIA GPU where warp-lang is installed and MJX_GPU_DEFAULT_WARP=true):
    smol-dsl writes bodies into MJX-JAX's fields and Brax makes its data for MJX-JAX only."""
    if implementation != MJX_IMPLEMENTATION:
        raise UserInputError(
            f"MJX built the task's model for its {implementation!r} implementation, and smol-dsl runs MJX as "
            f"MJX-JAX only (MuJoCo Warp is not supported yet); unset MJX_GPU_DEFAULT_WARP, which asks MJX for Warp"
        )
