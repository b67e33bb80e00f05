"""How many examples a property or fuzz test draws: every one in the full suite; an eighth (at
least one) in the fast tier, `pytest -m "not slow"`, where the edit loop wants its answer in
a couple of minutes (conftest says which run this is, before the tests are collected)."""

from __future__ import annotations

import math

FAST_SHARE = 1 / 8
fast_tier = False  # set by conftest for a run that leaves the slow tests out


def examples(count: int) -> int:
    """`count` examples, or the fast tier's share of them."""
    return max(1, math.ceil(count * FAST_SHARE)) if fast_tier else count
