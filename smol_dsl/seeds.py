"""Which seeds give distinct random streams: `check_seed(seed, "--seed")`.

A seed becomes a key with `jax.random.key(seed)`, which keeps its low 32 bits (without
64-bit mode, JAX's default): seed 4294967296 is bit for bit seed 0, and -1 is 4294967295.
So exactly the seeds 0 .. 2**32 - 1 give different runs; any other seed would repeat one of
them under another name (and `report` would count it as another seed). This module is
light (JAX is imported only to make a key), so every command can check a seed before
anything heavy is imported.

A run's seed gives its schedule's random draws through `schedule_key(seed)`: `run`,
`sweep` and `plot --seed` draw the same values for the same seed.
"""

from __future__ import annotations

import operator
from typing import TYPE_CHECKING

from smol_dsl.errors import UserInputError

if TYPE_CHECKING:
    import jax

SEED_MIN = 0
SEED_MAX = 2**32 - 1
"""The seeds that give distinct random streams: SEED_MIN .. SEED_MAX."""


class SeedError(UserInputError, ValueError):
    """A seed outside SEED_MIN .. SEED_MAX, or not a whole number."""


def check_seed(seed: object, option: str = "seed") -> int:
    """`seed` as an int if it is a whole number from 0 to 2**32 - 1; else a SeedError whose
    message names `option` (for example "--seed" or "--first-seed") and the accepted range."""
    if isinstance(seed, bool):
        raise SeedError(f"{option} {seed!r}: a seed is a whole number from {SEED_MIN} to {SEED_MAX}")
    try:
        value = operator.index(seed)  # int, or numpy's integers; not floats or strings
    except TypeError:
        raise SeedError(f"{option} {seed!r}: a seed is a whole number from {SEED_MIN} to {SEED_MAX}") from None
    if not SEED_MIN <= value <= SEED_MAX:
        if -(2**63) <= value < 2**63:
            why = f"JAX keeps a seed's low 32 bits, so {value} would repeat seed {value % 2**32}"
        else:
            why = "JAX does not take a seed past 64 bits"
        raise SeedError(f"{option} {value}: seeds are whole numbers from {SEED_MIN} to {SEED_MAX} (2**32 - 1); {why}")
    return value


SCHEDULE_STREAM = 0x5CED
"""Folded into a seed's key for its schedule's draws, so that they are independent of the
run's other random numbers (its CVT, its initial policies) drawn from the same seed."""


def schedule_key(seed: int) -> jax.Array:
    """The key from which a run of `seed` draws its schedule's random segments."""
    import jax

    return jax.random.fold_in(jax.random.key(seed), SCHEDULE_STREAM)
