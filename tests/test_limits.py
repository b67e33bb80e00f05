"""The limits of the language: the number of segments and of random draws, which keep evaluation
memory-linear, and the nesting of expressions, which keeps recursion out of reach. Past a
limit, a schedule gets one located error."""

from __future__ import annotations

from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from checking import assert_finite_everywhere, check_cli

import smol_dsl
from smol_dsl.language.compiler import MAX_SEGMENTS

# ----------------------------------------------------------------------------- segments and draws


def segments_text(count: int, body: str = "constant 1.5") -> str:
    lines = []
    for i in range(count):
        a, b = Fraction(9 * i, 10 * count), Fraction(9 * (i + 1), 10 * count)
        lines.append(f"{a.numerator}/{a.denominator} .. {b.numerator}/{b.denominator}: {body}")
    return "\n".join([*lines, "90% .. 100%: tail", ""])


def test_more_segments_than_the_limit_is_a_located_error(tmp_path, capsys):
    code, err = check_cli(tmp_path, segments_text(MAX_SEGMENTS), capsys)  # + the tail
    assert code == 2
    assert f"hostile.sched:{MAX_SEGMENTS + 1}:1: error: the schedule has {MAX_SEGMENTS + 1} segments" in err


@pytest.mark.slow  # compiles the largest schedule the language takes
def test_evaluation_memory_does_not_grow_with_the_number_of_segments():
    t = jnp.linspace(0.0, 1.0, 100_000)

    def temp_bytes(schedule: smol_dsl.Schedule) -> int:
        compiled = jax.jit(schedule.alpha).lower(t).compile()
        return compiled.memory_analysis().temp_size_in_bytes

    few = smol_dsl.parse(segments_text(9, "random 0.5 .. 1.5"))
    many = smol_dsl.parse(segments_text(MAX_SEGMENTS - 1, "random 0.5 .. 1.5"))
    assert np.isfinite(np.asarray(many.alpha(t))).all()
    # one select over every segment held segments x len(t) values: ~400 MB here
    assert temp_bytes(many) < 2 * temp_bytes(few) + 4 * MAX_SEGMENTS * 100


def test_too_many_random_draws_in_all_is_a_located_error():
    text = "0% .. 45%: random 1 .. 2 every 5e-7\n45% .. 90%: random 1 .. 2 every 5e-7\n90% .. 100%: tail\n"
    with pytest.raises(smol_dsl.ScheduleError, match="draws") as caught:
        smol_dsl.parse(text)
    assert caught.value.line == 2


# ----------------------------------------------------------------------------- nesting


@pytest.mark.parametrize(
    "expression",
    [
        "2**" * 500 + "0",
        "(0+" * 1000 + "0" + ")" * 1000,
        "-" * 2000 + "1",
        "sin(" * 300 + "t" + ")" * 300,
        " + ".join(["t"] * 500),
    ],
    ids=["power chain", "brackets", "signs", "calls", "long sum"],
)
def test_deep_nesting_is_a_located_error_not_a_crash(expression, tmp_path, capsys):
    code, err = check_cli(tmp_path, f"0% .. 90%: expr 1 + {expression}\n90% .. 100%: tail\n", capsys)
    assert code == 2
    assert "hostile.sched:1:" in err and "nested too deeply" in err and "hint:" in err


@pytest.mark.parametrize(
    "expression", ["(t/100 + " * 90 + "1" + ")" * 90, "sin(" * 6 + "t" + ")" * 6], ids=["brackets", "calls"]
)
def test_nesting_below_the_limit_verifies_or_fails_cleanly(expression):
    try:
        schedule = smol_dsl.parse(f"0% .. 90%: expr 2 + {expression}\n90% .. 100%: tail\n")
    except smol_dsl.ScheduleError as error:
        assert error.line == 1
    else:
        assert_finite_everywhere(schedule, [100])
