"""The float32 magnitudes a schedule's values and their intermediates must keep within.

Kept apart from `smol_dsl.language.float32` (the proof, which needs sympy and mpmath) so
that the tasks' physical ranges can be checked against them without either.
"""

UNIT = 2.0**-24
"""Unit roundoff of float32 (round to nearest)."""
SAFE_MAX = 2.0**120
"""Largest magnitude any intermediate value may reach (float32 overflows at 2**128)."""
SAFE_MIN = 2.0**-120
"""Smallest magnitude of a divisor or a logarithm's argument after rounding (2**-126 flushes to 0)."""
TINY = 2.0**-126
"""Absolute error of one underflow: a float32 result this small may be flushed to 0."""
