"""The factors each task's physics can take: where random policies' rollouts stay finite.

For each kind of channel (gear, mass, friction, gravity), the whole body is scaled by a
factor 10**(k/8) in that kind alone and `--policies` freshly initialised policies are rolled
out for `--episode-length` steps (real physics, `--physics` spring or mjx, the task's own
scoring, one compilation: the body is a traced input). For each kind and direction the largest k (up to 36 decades:
float32 ends near 3.4e38) at which every rollout's fitness and descriptors are finite is
found by doubling k, then bisecting (as if finiteness held up to an edge and not beyond,
which the printed trials show). Prints every trial and, per kind, the finite range: what
`TaskSpec.factor_ranges` (smol_dsl/tasks/catalog.py) states for that physics.

Usage: python benchmarks/factor_ranges.py walker2d [--physics mjx] [--episode-length 1000] [--policies 16]
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from collections.abc import Callable

warnings.filterwarnings("ignore")
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

KINDS = ("gear", "mass", "friction", "gravity")
STEPS = 8  # trials per decade
LARGEST = 36 * STEPS  # 10**36: float32 ends near 3.4e38


def finite_edges(
    task_name: str, episode_length: int, policies: int, seed: int, physics: str = "spring"
) -> dict[str, tuple[float, float]]:
    """Per kind, the lowest and highest factor 10**(k/STEPS) at which every rollout is finite."""
    from smol_dsl.tasks import make_task

    task = make_task(task_name, episode_length=episode_length, physics=physics).with_channels(KINDS)
    params = task.init_policies(jax.random.key(seed), policies)
    start = task.episode_start(seed)
    score = task.scoring_fn()
    edges = {}
    for c, kind in enumerate(KINDS):

        def finite(exponent: int, c: int = c, kind: str = kind) -> bool:
            factor = 10.0 ** (exponent / STEPS)
            body = jnp.ones(len(KINDS), dtype=jnp.float32).at[c].set(np.float32(factor))
            fitnesses, descriptors = score(params, body, start)
            ok = np.isfinite(np.asarray(fitnesses)) & np.isfinite(np.asarray(descriptors)).all(axis=-1)
            print(f"  {kind} {factor:.3g}: {ok.mean():.2f} finite", flush=True)
            return bool(ok.all())

        low, high = -largest_finite(lambda k: finite(-k)), largest_finite(finite)
        edges[kind] = (10.0 ** (low / STEPS), 10.0 ** (high / STEPS))
    return edges


def largest_finite(finite: Callable[[int], bool]) -> int:
    """The largest k in 0 .. LARGEST with finite(k), by doubling then bisecting."""
    good, step = 0, 1
    while good + step <= LARGEST and finite(good + step):
        good, step = good + step, step * 2
    bad = min(good + step, LARGEST + 1)
    while bad - good > 1:
        middle = (good + bad) // 2
        good, bad = (middle, bad) if finite(middle) else (good, middle)
    return good


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("task")
    parser.add_argument("--physics", choices=("spring", "mjx"), default="spring")
    parser.add_argument("--episode-length", type=int, default=1000)
    parser.add_argument("--policies", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    started = time.perf_counter()
    print(f"{args.task} on {args.physics}: {args.policies} random policies, {args.episode_length} steps")
    edges = finite_edges(args.task, args.episode_length, args.policies, args.seed, args.physics)
    for kind, (low, high) in edges.items():
        print(f"finite_range_{kind}: {low:.3g} .. {high:.3g}")
    print(f"seconds: {time.perf_counter() - started:.0f}")


if __name__ == "__main__":
    main()
