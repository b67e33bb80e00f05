"""How the rollouts are compiled: XLA options that make them faster on CPUs and leave every
result bit for bit what XLA's default compilation gives.

Brax's spring pipeline is thousands of tiny operations per step (dot products and sums of
batched 3-vectors, 128 x 3 at a time), and XLA:CPU hands its small dots and reductions to
YNNPACK, whose kernels cost more per call than the work they do: in a walker2d rollout
(batch 128, 100 steps, profiled with `jax.profiler`) they took about 12% of the kernel time.
With YNNPACK kept for reductions only (`xla_cpu_experimental_ynn_fusion_type`
`LIBRARY_FUSION_TYPE_REDUCE`; XLA's default also gives it individual dots) XLA emits those
dots itself: measured side by side, interleaved, walker2d's rollouts ran 16-19% faster on
jax 0.10 and 8% faster on jax 0.12, and compiled 1-1.5 s sooner.

Whether the results stay bit for bit depends on the jax line and the body: XLA's own dot
kernels sum in YNNPACK's order for some bodies and not for others (jax 0.10's ant differs in
the last bits, and a chaotic rollout grows that; so do jax 0.12's on some machines, with
the same wheels, so the ants are left to XLA's defaults on every line; jax 0.11, the line of
a typical offline GPU node, was measured as the others). `EXACT_TASKS` lists, per jax line,
the tasks measured bit for bit (every output of 8 random policies over 40 steps, and of 16 to
128 over 100 to 1000 steps, in one and in three channels, transitions included);
tests/test_compiling.py holds it on the installed line. Any other task, jax line or
platform is compiled with XLA's defaults, and so is everything where XLA refuses the option,
and every task on MJX (`Task.compiler_options`: measured on Brax's spring pipeline only).
"""

from __future__ import annotations

from functools import cache

FAST_CPU_OPTIONS = {"xla_cpu_experimental_ynn_fusion_type": "LIBRARY_FUSION_TYPE_REDUCE"}
"""XLA:CPU options of the rollouts: YNNPACK for reductions only, XLA's own kernels for dots."""

UNIFORM_BODIES = frozenset({"walker2d", "halfcheetah", "hopper"})
EXACT_TASKS = {
    (0, 10): UNIFORM_BODIES,  # the ants' results differ in the last bits (measured on 0.10.2)
    (0, 11): UNIFORM_BODIES,  # measured on 0.11.2 (the jax of a typical offline GPU node)
    (0, 12): UNIFORM_BODIES,  # the ants differ in the last bits on some machines (0.12.0.1)
}
"""Per jax line (major, minor), the tasks whose results `FAST_CPU_OPTIONS` leaves bit for bit."""


def jax_line() -> tuple[int, int]:
    """The installed jax's (major, minor) version."""
    import jax

    major, minor = jax.__version__.split(".")[:2]
    return int(major), int(minor)


@cache
def compiler_options(task_name: str, platform: str) -> dict[str, str] | None:
    """The compiler options of a task's programs on `platform` ("cpu", "gpu", ...):
    `FAST_CPU_OPTIONS` on CPUs for a task in `EXACT_TASKS` of the installed jax line whose
    XLA takes them, else None (XLA's defaults)."""
    if platform != "cpu" or task_name not in EXACT_TASKS.get(jax_line(), ()):
        return None
    return dict(FAST_CPU_OPTIONS) if accepted(tuple(FAST_CPU_OPTIONS.items())) else None


@cache
def accepted(options: tuple[tuple[str, str], ...]) -> bool:
    """Whether XLA compiles a program with these options (a later XLA may no longer know an
    experimental one: "No such compile option")."""
    import jax
    import jax.numpy as jnp

    try:
        jax.jit(lambda x: x + 1, compiler_options=dict(options)).lower(jnp.zeros((), jnp.float32)).compile()
    except Exception:  # jaxlib's runtime error: the option or its value is unknown
        return False
    return True
