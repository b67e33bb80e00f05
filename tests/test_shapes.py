"""The shape registry: a new shape given by a formula is one unit plus one grammar rule."""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np
import pytest
import sympy as sp

import smol_dsl
from smol_dsl.language import shapes
from smol_dsl.language.grammar import grammar_text, reserved_words

COSINE_RULE = 'cosine_shape: "cosine" expr "->" expr'
TAIL = "90% .. 100%: tail\n"


class Cosine(shapes.Shape):
    """A cosine ease from a to b: the whole of a new shape, apart from its grammar rule."""

    keyword = "cosine"
    usage = "cosine a -> b"
    meaning = "`a + (b − a)·(1 − cos(π·u))/2`"

    def compile(self, segment, start, end):
        a, b = segment.value(start, "start value"), segment.value(end, "end value")
        return self.single_piece(segment, a + (b - a) * (1 - sp.cos(sp.pi * segment.u)) / 2)


def test_a_formula_shape_is_one_unit_and_one_rule():
    with shapes.registered(Cosine(), COSINE_RULE):
        assert "cosine" in reserved_words()
        schedule = smol_dsl.parse("bounds 1 .. 1.5\n0% .. 90%: cosine 1.5 -> 1 decreasing\n" + TAIL)
        piece = schedule.certificate.pieces[0]
        assert (piece.kind, piece.minimum, piece.maximum, piece.monotone, piece.exact) == (
            "cosine",
            1.0,
            1.5,
            "decreasing",
            True,
        )
        assert 0 < piece.float32_error < 1e-6  # the running error analysis of its formula
        t = np.linspace(0, 0.9, 901, endpoint=False)
        expected = 1.5 - 0.5 * (1 - np.cos(np.pi * t / 0.9)) / 2
        np.testing.assert_allclose(jax.jit(schedule.alpha)(t), expected, atol=1e-6)
        np.testing.assert_array_equal(schedule.phase_alphas(100)[90:], 1.0)
        assert schedule.segments[0].kind == "cosine"
        with pytest.raises(smol_dsl.ScheduleError, match="`cosine` is a reserved word"):
            smol_dsl.parse("let cosine = 1\n0% .. 100%: tail\n")
        with pytest.raises(smol_dsl.ScheduleError, match="the start value of segment 1 is not a finite real"):
            smol_dsl.parse("0% .. 90%: cosine log(-1) -> 1\n" + TAIL)
        with pytest.raises(smol_dsl.ScheduleError) as caught:
            smol_dsl.parse("0% .. 90%: cosin 1 -> 2\n" + TAIL)
        assert caught.value.hint == (
            "did you mean `cosine`? The segment kinds are constant, linear, bell, random, expr, tail, cosine"
        )
        with pytest.raises(smol_dsl.ScheduleError, match="increasing but is not"):
            smol_dsl.parse("0% .. 90%: cosine 1.5 -> 1 increasing\n" + TAIL)
    assert "cosine" not in reserved_words() and "cosine" not in grammar_text()
    with pytest.raises(smol_dsl.ScheduleError, match="unexpected 'cosine'"):
        smol_dsl.parse("0% .. 90%: cosine 1.5 -> 1\n" + TAIL)
    assert float(smol_dsl.parse("let cosine = 1.5\n0% .. 90%: constant cosine\n" + TAIL).alpha(0.5)) == 1.5


def test_the_grammar_rules_and_the_registry_must_match():
    with shapes.registered(Cosine()), pytest.raises(RuntimeError, match=r"units without a rule \['cosine'\]"):
        smol_dsl.parse("0% .. 100%: tail\n")
    with pytest.raises(ValueError, match="registered already"):
        shapes.register(shapes.unit("linear"))
    with pytest.raises(ValueError, match="must define `cosine_shape`"):
        shapes.register(Cosine(), 'cos_shape: "cos" expr')
    assert shapes.keywords() == ("constant", "linear", "bell", "random", "expr", "tail")
    assert smol_dsl.load("human").certificate.pieces[0].kind == "bell to peak"


def test_every_shape_is_in_the_language_reference():
    reference = (Path(__file__).resolve().parent.parent / "docs" / "language.md").read_text(encoding="utf-8")
    for shape in shapes.units():
        assert f"| `{shape.usage}` | {shape.meaning} |" in reference, shape.keyword
